"""Which episodes of a task a run or a dataset takes (``doabench run --episodes N``, ``--cells``;
``doabench make-dataset --episodes N``), and the record of it in the results (``task.selection``,
docs/results-format.md) and in a dataset's config (``selection``, docs/hdf5-schema.md).

A grid task's episodes lie cell after cell (:mod:`doabench.envs.simulated`: episode ``i`` is
episode ``i % per_cell`` of cell ``i // per_cell``). Its first N episodes would all come from the
first cell, so ``--episodes N`` on a grid is *stratified*: every cell gives its first
``N // cells`` episodes, and the other ``N % cells`` come one each from cells evenly spaced over
the grid (6 episodes of an 18-cell grid: one from every third cell). ``--cells`` restricts a grid run to some of its cells (all their episodes, or N of them
stratified the same way). On other tasks ``--episodes N`` takes the first N. A run that takes
fewer than all of a task's episodes is *partial*: the leaderboards list it apart, unranked.
"""
from __future__ import annotations

import difflib
from typing import Any, Sequence

from doabench.errors import ConfigError


def grid_layout(spec: Any, n_total: int) -> list[tuple[str, list[int]]] | None:
    """``[(cell task id, its episode indices)]`` of a grid task, in the grid's order; None when
    the task has no cells (or its episodes do not split evenly over them)."""
    cells = [str(c) for c in (spec.params.get("cells") or [])]
    if not cells or n_total % len(cells):
        return None
    per = n_total // len(cells)
    return [(cell, list(range(i * per, (i + 1) * per))) for i, cell in enumerate(cells)]


def parse_cells(text: str | Sequence[str] | None) -> list[str] | None:
    """``--cells`` text (comma-separated cell task ids) -> list, None when not given."""
    if text is None:
        return None
    items = [s.strip() for s in (text.split(",") if isinstance(text, str) else text)]
    items = list(dict.fromkeys(s for s in items if s))
    if not items:
        raise ConfigError("--cells needs at least one cell task id (comma-separated; doabench list tasks)")
    return items


def select_episodes(spec: Any, n_total: int, episodes: int | Sequence[int] | None = None,
                    cells: Sequence[str] | None = None) -> tuple[list[int], dict[str, Any]]:
    """The episode indices a run takes, sorted, and the ``task.selection`` record of the rule:
    ``{"rule": "all" | "first" | "stratified" | "cells" | "indices", "episodes": N or None,
    "cells": [cell ids] or None}``."""
    grid = grid_layout(spec, n_total)
    if cells is not None:
        if grid is None:
            raise ConfigError(f"--cells applies to grid tasks; task {spec.id!r} has no cells")
        known = [c for c, _ in grid]
        unknown = [c for c in cells if c not in known]
        if unknown:
            close = difflib.get_close_matches(unknown[0], known, n=1)
            hint = f"; did you mean {close[0]}?" if close else f" (its cells: {', '.join(known[:3])}, ...)"
            raise ConfigError(f"task {spec.id!r} has no cell {unknown[0]!r}{hint}")
        grid = [(c, idx) for c, idx in grid if c in cells]
        cells = [c for c, _ in grid]  # in the grid's order
        pool = sorted(i for _, idx in grid for i in idx)
    else:
        pool = list(range(n_total))
    if episodes is not None and not isinstance(episodes, int):
        indices = sorted({int(i) for i in episodes})
        bad = [i for i in indices if not 0 <= i < n_total]
        if bad:
            raise ConfigError(f"task {spec.id!r} has {n_total} episodes; episode {bad[0]} does not exist")
        return indices, {"rule": "indices", "episodes": len(indices), "cells": None}
    if episodes is not None and episodes < 1:
        raise ConfigError(f"--episodes must be at least 1, got {episodes}")
    if episodes is None or episodes >= len(pool):
        rule = "cells" if cells is not None else "all"
        return pool, {"rule": rule, "episodes": None, "cells": cells}
    if grid is None:
        return pool[:episodes], {"rule": "first", "episodes": episodes, "cells": None}
    rounds, rest = divmod(episodes, len(grid))
    taken = [i for _, idx in grid for i in idx[:rounds]]
    # the last, incomplete round: cells evenly spaced over the grid, not its first ones
    taken += [grid[int((k + 0.5) * len(grid) / rest)][1][rounds] for k in range(rest)]
    return sorted(taken), {"rule": "stratified", "episodes": episodes, "cells": cells}


def describe_selection(spec: Any, n_total: int, indices: Sequence[int], selection: dict[str, Any]) -> str:
    """What a selection takes, in words: ``6 of 360 episodes, spread over the 18 cells (one each
    from 6 of them)``, ``the first 6 of 100 episodes``, ``all 360 episodes``."""
    n = len(indices)
    rule = selection.get("rule")
    grid = grid_layout(spec, n_total)
    if rule in ("all", "cells") and n == n_total:
        return f"all {n_total} episodes"
    if rule in ("stratified", "cells") and grid is not None:
        cells = selection.get("cells") or [c for c, _ in grid]
        chosen = set(indices)
        used = sum(1 for c, idx in grid if c in cells and chosen.intersection(idx))
        whose = f"the {len(cells)} cells" if len(cells) == len(grid) else f"{len(cells)} of the {len(grid)} cells"
        share = "" if used == len(cells) else f" (one each from {used} of them)"
        return f"{n} of {n_total} episodes, spread over {whose}{share}"
    if rule == "first":
        return f"the first {n} of {n_total} episodes"
    return f"{n} of {n_total} episodes"


def cells_covered(spec: Any, rows: Sequence[dict[str, Any]]) -> dict[str, int] | None:
    """``{"cells_run": cells with at least one episode in rows, "cells_total": the grid's}``, None
    for a task without cells (rows name their cell task in ``task``)."""
    cells = [str(c) for c in (spec.params.get("cells") or [])]
    if not cells:
        return None
    return {"cells_run": len({r.get("task") for r in rows} & set(cells)), "cells_total": len(cells)}
