"""rodctl: an experiment runner for vision-based shape servoing of elastic rods."""

__version__ = "0.1.0"
