"""The commands of ``tunnelsim``, one module per topic; each registers its own commands
(``register(commands)``) and ``survey.cli.registry`` puts them under one parser."""

__all__: list[str] = []
