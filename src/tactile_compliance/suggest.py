"""``did_you_mean``: the one "did you mean" of a mistyped name (model, preset, input
strategy, config key), torch-free, for the one-line errors of docs/cli.md."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

__all__ = ["did_you_mean"]


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` (or ``'x' or 'y'``) for the choices closest to ``word``
    (``difflib.get_close_matches``, case-insensitive, cutoff 0.6), else ``""``.

    Deterministic: the same word and choices give the same text.
    """
    options = list(dict.fromkeys(str(c) for c in choices))
    by_lower = {c.lower(): c for c in options}
    close = difflib.get_close_matches(str(word).lower(), list(by_lower), n=2, cutoff=0.6)
    if not close:
        return ""
    return " (did you mean " + " or ".join(f"'{by_lower[c]}'" for c in close) + "?)"
