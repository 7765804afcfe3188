"""Few-shot protocols: which views train and which views test (the published protocols, table below).

*Spread evenly* means ``idx[round(linspace(0, len(idx) - 1, n_views))]``, rounding half to even (``np.round``).

=============  =======================================================================================
protocol       train / test
=============  =======================================================================================
``extreme``    NeRF Synthetic Extreme: 3 per-scene views (:data:`EXTREME_VIEWS`, looked up by the scene
               name = folder name, case-insensitive) as indices *into the train split*; ``views``
               replaces the table (then any scene name works).  Test: the whole test split.
``infonerf4``  InfoNeRF's 4 views ``[26, 86, 2, 55]`` into the train split.  Test: the test split.
``random8``    ``n_views`` (default 8) distinct train-split views drawn with
               ``np.random.default_rng(seed).choice(n_train, n_views, replace=False)`` (kept in draw
               order).  Test: the test split.
``spread``     ``n_views`` (default 3) train-split views spread evenly.  Test: the test split (for a split
               scene of one's own, with no published views).
``llff``       Over *all* images: test = every 8th (``index % 8 == 0``); train = ``n_views`` (default 3)
               of the rest, spread evenly.
``dtu``        DTU's few-shot protocol (RegNeRF, PixelNeRF) over a 49-image DTU scan: train = the first
               ``n_views`` (default 3, at most 9) of :data:`DTU_TRAIN_VIEWS`; test = :data:`DTU_TEST_VIEWS`
               (the other images are not used).
``views``      Explicit ``views``.  Split scenes (kind ``'object'`` with a non-empty ``'val'`` or ``'test'``
               split: Blender, or nerfstudio files with split lists): indices into the train split, test =
               the test split.  Others: indices into *all* images; test = the scene's test split minus the
               training views, or, when that is empty, every image not used for training.
``all``        The whole train split; test = the test split (empty for an ngp file without splits).
=============  =======================================================================================

Errors are :class:`senerf.errors.InputError` naming the command-line field (``--views``, ``--n-views``,
``--protocol``, and ``--test-views`` for :func:`spread_views`).
"""

from __future__ import annotations

import numbers

import numpy as np

from ..errors import InputError
from .llff import llff_splits
from .scene import Scene

__all__ = ["fewshot_split", "spread_views", "PROTOCOLS", "EXTREME_VIEWS", "INFONERF4_VIEWS", "DTU_TRAIN_VIEWS",
           "DTU_TEST_VIEWS"]

#: NeRF Synthetic Extreme (3 views, indices into the train split), REFERENCE section 5.
EXTREME_VIEWS = {
    "chair": (26, 31, 32),
    "drums": (3, 9, 14),
    "ficus": (12, 36, 56),
    "hotdog": (31, 33, 48),
    "lego": (0, 1, 51),
    "materials": (47, 63, 73),
    "ship": (36, 55, 66),
    "mic": (35, 65, 82),
}
#: InfoNeRF's NeRF Synthetic 4-view protocol (indices into the train split).
INFONERF4_VIEWS = (26, 86, 2, 55)
#: DTU's few-shot training views, in order (the first 3, 6 or 9), and its test views (indices into the 49 images).
DTU_TRAIN_VIEWS = (25, 22, 28, 40, 44, 48, 0, 8, 13)
DTU_TEST_VIEWS = (1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43, 45, 46, 47)
PROTOCOLS = ("extreme", "infonerf4", "random8", "spread", "llff", "dtu", "views", "all")
#: The number of training views of the protocols that take ``n_views``, when it is not given.
_DEFAULT_N_VIEWS = {"random8": 8, "spread": 3, "llff": 3, "dtu": 3}


def _views(views, n: int, what: str, field: str = "--views") -> np.ndarray:
    """``views`` checked (integers, distinct, in ``[0, n)``, at least one) as int64; ``InputError`` naming
    ``field`` (``--protocol`` for a protocol's own views: no flag of the user's is wrong)."""
    if isinstance(views, (str, bytes)) or not hasattr(views, "__iter__"):
        raise InputError(f"expected a list of view indices, got {views!r}", field=field)
    out = []
    for v in views:
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
            raise InputError(f"view index {v!r} is not an integer", field=field)
        if not 0 <= int(v) < n:
            raise InputError(f"view index {v} out of range [0, {n}) ({what})", field=field)
        if int(v) in out:
            raise InputError(f"duplicate view index {v}", field=field)
        out.append(int(v))
    if not out:
        raise InputError("empty view list", field=field)
    return np.asarray(out, np.int64)


def _n_views(n_views, default: int, n_max: int, what: str, protocol: str) -> int:
    if n_views is None:
        if not 1 <= default <= n_max:   # the protocol's own count: --n-views was not given
            raise InputError(f"protocol {protocol!r} takes {default} views, and the scene has {n_max} {what}",
                             field="--protocol")
        n_views = default
    if isinstance(n_views, (bool, np.bool_)) or not isinstance(n_views, numbers.Integral):
        raise InputError(f"expected an integer, got {n_views!r}", field="--n-views")
    if not 1 <= int(n_views) <= n_max:
        raise InputError(f"must be in [1, {n_max}] ({what}), got {n_views}", field="--n-views")
    return int(n_views)


def _test_split(scene: Scene) -> np.ndarray:
    if scene.splits["test"].size == 0:
        raise InputError(f"scene {scene.name!r} has no test split; use protocol 'llff' or 'views'", field="--protocol")
    return scene.splits["test"]


def spread_views(idx, k: int, field: str = "--test-views") -> np.ndarray:
    """``k`` of the view indices ``idx (n,)`` spread evenly (module docstring; the first and the last included),
    int64 ``(k,)`` in ``idx``'s order; all of ``idx`` when ``k`` is ``n``.

    Example:
        >>> spread_views(np.arange(100, 300), 5).tolist()
        [100, 150, 200, 249, 299]

    Raises:
        InputError: naming ``field`` when ``k`` is below 1 or above ``n``, or ``idx`` is empty.
    """
    idx = np.asarray(idx, dtype=np.int64).reshape(-1)
    if isinstance(k, bool) or not isinstance(k, numbers.Integral) or not 1 <= k <= idx.size:
        raise InputError(f"expected a number of views from 1 to the {idx.size} there are, got {k!r}", field=field)
    return idx[np.round(np.linspace(0, idx.size - 1, int(k))).astype(np.int64)]


def fewshot_split(scene: Scene, protocol: str = "extreme", views=None, n_views=None, seed: int = 0):
    """Training and test view indices of a few-shot protocol (see the module docstring for each one).

    Args:
        protocol: one of :data:`PROTOCOLS`.
        views: explicit view indices (``'views'``; overrides the table for ``'extreme'``).
        n_views: number of training views (``'llff'``, ``'spread'``: default 3; ``'random8'``: default 8).
        seed: seed of ``'random8'``.

    Returns:
        ``(train_idx, test_idx)``: disjoint int64 indices into the scene's arrays, train in protocol order.
    """
    if protocol not in PROTOCOLS:
        raise InputError(f"unknown protocol {protocol!r}; expected one of {', '.join(PROTOCOLS)}",
                         field="--protocol")
    if views is not None and protocol not in ("extreme", "views"):
        raise InputError(f"explicit views are not used by protocol {protocol!r} (give --views without "
                         "--protocol; in Python, protocol 'views')", field="--views")
    if n_views is not None and protocol not in _DEFAULT_N_VIEWS:
        raise InputError(f"not used by protocol {protocol!r} (only 'llff', 'dtu', 'random8' and 'spread')",
                         field="--n-views")
    train_split = scene.splits["train"]
    n_train = int(train_split.size)
    if protocol in ("extreme", "infonerf4") and views is None:
        table = INFONERF4_VIEWS if protocol == "infonerf4" else EXTREME_VIEWS.get(scene.name.lower())
        if table is None:
            raise InputError(f"no Extreme views known for scene {scene.name!r} (known: "
                             f"{', '.join(sorted(EXTREME_VIEWS))}); pass views explicitly", field="--views")
        what = f"the {protocol} protocol's views {tuple(table)} index the train split; choose views with --views"
        return train_split[_views(table, n_train, what, field="--protocol")], _test_split(scene)
    if protocol == "views" and views is None:
        raise InputError("protocol 'views' needs explicit view indices", field="--views")
    if protocol == "extreme" or (protocol == "views" and scene.kind == "object"
                                 and (scene.splits["val"].size or scene.splits["test"].size)):
        return train_split[_views(views, n_train, "indices into the train split")], _test_split(scene)
    if protocol in ("random8", "spread"):
        test = _test_split(scene)
        k = _n_views(n_views, _DEFAULT_N_VIEWS[protocol], n_train, "train-split views", protocol)
        if protocol == "spread":
            return spread_views(train_split, k), test
        return train_split[np.random.default_rng(seed).choice(n_train, size=k, replace=False).astype(np.int64)], test
    if protocol == "all":
        if n_train == 0:
            raise InputError(f"scene {scene.name!r} has an empty train split", field="--protocol")
        return train_split.copy(), scene.splits["test"].copy()
    n = scene.n_images
    if protocol == "llff":
        held_out = llff_splits(n)
        rest = held_out["train"]
        k = _n_views(n_views, _DEFAULT_N_VIEWS[protocol], int(rest.size), "non-held-out images", protocol)
        return spread_views(rest, k), held_out["test"]

    if protocol == "dtu":
        if n != 49:
            raise InputError(f"the dtu protocol indexes the 49 images of a DTU scan; scene {scene.name!r} has {n}",
                             field="--protocol")
        k = _n_views(n_views, _DEFAULT_N_VIEWS[protocol], len(DTU_TRAIN_VIEWS), "DTU few-shot views", protocol)
        return np.array(DTU_TRAIN_VIEWS[:k], dtype=np.int64), np.array(DTU_TEST_VIEWS, dtype=np.int64)

    # protocol == "views", views indexing all images
    train = _views(views, n, "indices into all images")
    test = np.setdiff1d(scene.splits["test"], train)
    if test.size == 0:
        test = np.setdiff1d(np.arange(n, dtype=np.int64), train)
    if test.size == 0:
        raise InputError("every image is a training view; nothing left to test on", field="--views")
    return train, test
