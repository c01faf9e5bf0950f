"""The symmetric action loss (report 000 in the seed reports): an auxiliary term that pulls mirrored action groups
together.

`sym.groups` pairs half-open index ranges of equal length, `a:b=c:d`, separated by commas; `i` alone means `i:i+1`.
The term is the mean over pairs of the per-pair MSE (over valid samples and the pair's dimensions), as the seed
averages its two groups. With `compare = "mean"` the policy means are compared, after flipping the sign of the
right-hand indices listed in `sym.negate` (joints whose axis is mirrored, so that mirrored motion is `-a`); with
`compare = "log_prob"` the per-dimension log-probabilities of the stored actions are compared, which is what the seed
does and which is invariant to such sign flips.

Parsing is plain Python (config validation imports it without JAX).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from canter.errors import CanterError


class MirrorPair(NamedTuple):
    first: tuple[int, ...]  # the indices left of "=" in `a:b=c:d`
    mirror: tuple[int, ...]  # the indices right of "="
    signs: tuple[float, ...]  # applied to `mirror` when means are compared


def _parse_range(text: str, whole: str) -> tuple[int, ...]:
    start, sep, stop = text.strip().partition(":")
    try:
        first = int(start)
        last = int(stop) if sep else first + 1
    except ValueError:
        raise CanterError(
            f"sym.groups: cannot read range '{text.strip()}' in '{whole}'; write pairs like 3:7=7:11,11:14=14:17"
        ) from None
    if first < 0 or last <= first:
        raise CanterError(f"sym.groups: range '{text.strip()}' must be start:stop with 0 <= start < stop")
    return tuple(range(first, last))


def parse_groups(text: str, negate: tuple[int, ...] = ()) -> tuple[MirrorPair, ...]:
    """Parse `sym.groups` (and `sym.negate`) into mirror pairs, or raise a one-line CanterError."""
    pairs: list[MirrorPair] = []
    for item in (p for p in text.split(",") if p.strip()):
        first_text, sep, mirror_text = item.partition("=")
        if not sep:
            raise CanterError(f"sym.groups: '{item.strip()}' is not a pair; write a:b=c:d, e.g. 3:7=7:11")
        first, mirror = _parse_range(first_text, text), _parse_range(mirror_text, text)
        if len(first) != len(mirror):
            raise CanterError(
                f"sym.groups: '{item.strip()}' pairs {len(first)} with {len(mirror)} dimensions; "
                f"mirrored groups must have equal lengths"
            )
        pairs.append(MirrorPair(first, mirror, tuple(-1.0 if i in negate else 1.0 for i in mirror)))
    stray = sorted(set(negate) - {i for pair in pairs for i in pair.mirror})
    if stray:
        raise CanterError(f"sym.negate: indices {stray} are not on the right-hand side of any sym.groups pair")
    return tuple(pairs)


def check_action_range(pairs: tuple[MirrorPair, ...], act_dim: int, algo: str) -> None:
    top = max((i for pair in pairs for i in pair.first + pair.mirror), default=-1)
    if top >= act_dim:
        raise CanterError(
            f"sym.groups: index {top} is out of the action range 0..{act_dim - 1} of this env "
            f"({algo}); fix sym.groups or set sym.coef=0"
        )


def symmetric_loss(values: Any, pairs: tuple[MirrorPair, ...], mask: Any, use_signs: bool) -> Any:
    """Mean over pairs of the masked MSE between `values[:, first]` and `sign * values[:, mirror]`.

    `values` is [B, act_dim] (policy means, or per-dimension log-probabilities with `use_signs=False`)."""
    import jax.numpy as jnp

    count = jnp.maximum(jnp.sum(mask), 1.0)
    per_pair = []
    for pair in pairs:
        mirror = values[:, jnp.array(pair.mirror)]
        if use_signs:
            mirror = mirror * jnp.asarray(pair.signs, values.dtype)
        squared = jnp.square(values[:, jnp.array(pair.first)] - mirror).mean(axis=-1)
        per_pair.append(jnp.sum(squared * mask) / count)
    return jnp.mean(jnp.stack(per_pair))
