"""The package's error for bad input (below every module that reads input, the file helpers included)."""


class ConfigError(ValueError):
    """A configuration value or key is not allowed. The message names field, value and rule."""
