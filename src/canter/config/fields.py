"""How a config field is declared: its documentation, and the role that says whether it changes what is learned.

The role is the one rule for "which runs are seeds of one experiment" (`canter.config.experiment`): two runs are
seeds of one experiment when every field whose role is `LEARNING` is equal. The other roles name why a field does
not count:
- `SEED`: the run seed itself;
- `BUDGET`: how long a run trains (bench and resume extend runs by raising it);
- `OUTPUT`: where and how results are written, and how the work is split up, which never changes the numbers.
"""

from __future__ import annotations

from dataclasses import MISSING, Field, field
from typing import Any

LEARNING = "learning"
SEED = "seed"
BUDGET = "budget"
OUTPUT = "output"


def setting(doc: str, *, default: Any = MISSING, role: str = LEARNING) -> Any:
    """A dataclass field with its one-line documentation (the README's key table) and its role."""
    return field(default=default, metadata={"doc": doc, "role": role})


def role_of(f: Field) -> str:
    return f.metadata.get("role", LEARNING)
