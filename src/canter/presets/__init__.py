"""Preset overlay files (TOML). Each may hold `[env_overrides."pattern".section]` tables applied by env id."""
