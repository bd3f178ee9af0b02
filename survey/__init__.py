"""survey: the surveyor's workflow on top of ``sensors`` and ``raytrace``."""
