"""Scene files for the fake cell (TOML)."""
