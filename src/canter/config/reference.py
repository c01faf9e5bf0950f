"""The README's table of every config key, generated from the dataclasses so the docs cannot drift."""

from __future__ import annotations

from dataclasses import fields

from canter.config.schema import field_types, section_names, section_type
from canter.config.values import set_text, type_name


def docs_table() -> str:
    rows = ["| key | type | default | meaning |", "|---|---|---|---|"]
    for section in section_names():
        types_ = field_types(section)
        defaults = section_type(section)()
        for f in fields(defaults):
            shown = set_text(getattr(defaults, f.name))
            rows.append(
                f"| `{section}.{f.name}` | {type_name(types_[f.name])} | `{shown or '(empty)'}` "
                f"| {f.metadata.get('doc', '')} |"
            )
    return "\n".join(rows)
