"""Underwater vehicles in six degrees of freedom (``<name>.toml``, read by config/underwater.py)."""
