"""The configuration: a typed, frozen tree of sections, built from defaults < preset < config file < `--set`."""

from canter.config.schema import Config, build_config

__all__ = ["Config", "build_config"]
