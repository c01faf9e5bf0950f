"""A config value as --set text: what refusals suggest, plot labels and reports show, and the README's key table
lists, in the form `--set` reads back."""

from dataclasses import fields

import pytest

from canter.config.schema import Config, field_types, section_names
from canter.config.values import coerce, set_text


@pytest.mark.parametrize(
    ("value", "text"),
    [
        ((64, 64), "64,64"),
        ((256,), "256"),
        ((), ""),
        (None, "none"),
        (True, "true"),
        (False, "false"),
        (0.0003, "0.0003"),
        (1e-05, "1e-05"),
        (2.5e20, "2.5e+20"),
        (0.1, "0.1"),
        (1.0, "1.0"),
        (-3.5, "-3.5"),
        (2048, "2048"),
        (0, "0"),
        (-1, "-1"),
        ("Hopper-v5", "Hopper-v5"),
        ("", ""),
        ("a b,c", "a b,c"),
    ],
)
def test_set_text_hand_values(value, text):
    assert set_text(value) == text


def test_every_default_reads_back_from_its_set_text():
    config = Config()
    for section in section_names():
        types = field_types(section)
        for f in fields(getattr(config, section)):
            value = getattr(getattr(config, section), f.name)
            key = f"{section}.{f.name}"
            assert coerce(key, types[f.name], set_text(value)) == value, key
