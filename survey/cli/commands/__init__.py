"""The subcommands of ``tunnelsim``, grouped by topic; ``survey.cli`` builds the parser."""
