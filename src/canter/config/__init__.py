"""The configuration: a typed, frozen tree of sections, resolved from defaults < preset < config file < `--set`.

Modules: `fields` (how a key is declared, and its role), `schema` (the env and run sections, the `Config` tree and
the section registry), `algorithms` (what each algorithm declares), `values` (typed coercion), `overrides`
(`section.key` overrides from `--set` and TOML), `presets`, `build` (the layering), `validate`, `serialize`
(config.toml), `experiment` (which runs are seeds of one experiment) and `reference` (the README's key table).
This package never imports an algorithm: algorithms register their sections and specs with it.
"""
