"""Few-shot protocols: which views train and which views test (the published protocols, table below).

``fewshot_split(scene, protocol, views=None, n_views=None, seed=0) -> (train_idx, test_idx)``; both are
int64 arrays of indices into the scene's arrays (``scene.rgb``, ``scene.c2w``), train in protocol order.

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
``spread``     ``n_views`` (default 3) train-split views spread evenly over it:
               ``train[round(linspace(0, n_train - 1, n_views))]`` (rounding half to even).  Test: the test
               split.  For a split scene of one's own (no published views), keeping its test split held out.
``llff``       Over *all* images: test = every 8th (``index % 8 == 0``); train =
               ``rest[round(linspace(0, n_rest - 1, n_views))]`` with ``n_views`` default 3 (rounding half
               to even, ``np.round``).
``views``      Explicit ``views``.  Split scenes (kind ``'object'`` with a non-empty ``'val'`` or
               ``'test'`` split: Blender, or nerfstudio files with split lists): indices into the train
               split, test = test split.  LLFF and ngp files without splits: indices into *all* images;
               test = the scene's test split minus the training views, or, when that is empty, every
               image not used for training.
``all``        The whole train split; test = the test split (empty for an ngp file without splits).
=============  =======================================================================================

``spread_views(test_idx, k)`` keeps ``k`` of a protocol's test views, spread evenly over them (``senerf-fit
--test-views``: scoring fewer views where rendering all of them at full resolution takes long).

Errors are :class:`senerf.errors.InputError` naming the command-line field (``--views``,
``--n-views``, ``--protocol``): unknown protocol or scene, out-of-range or duplicate view index, too many
views, an empty test set where the protocol needs one.
"""

from __future__ import annotations

import numbers

import numpy as np

from ..errors import InputError
from .llff import LLFF_HOLDOUT
from .scene import Scene

__all__ = ["fewshot_split", "spread_views", "PROTOCOLS", "EXTREME_VIEWS", "INFONERF4_VIEWS", "LLFF_HOLDOUT",
           "DEFAULT_N_VIEWS", "explicit_n_views"]

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
PROTOCOLS = ("extreme", "infonerf4", "random8", "spread", "llff", "views", "all")
#: The number of training views of the protocols that take ``n_views``, when it is not given.
DEFAULT_N_VIEWS = {"random8": 8, "spread": 3, "llff": 3}


def explicit_n_views(protocol, n_views):
    """``n_views`` as a run records it: None when it is the protocol's default (:data:`DEFAULT_N_VIEWS`), so a
    count given at its default names the same run as one not given; any other value (or protocol) as it is.

    Example:
        >>> explicit_n_views("llff", 3), explicit_n_views("llff", 4), explicit_n_views("random8", 8)
        (None, 4, None)
    """
    if n_views is not None and isinstance(protocol, str) and n_views == DEFAULT_N_VIEWS.get(protocol):
        return None
    return n_views


def _as_view_list(views, n: int, what: str, table: str | None = None) -> np.ndarray:
    """Validate ``views`` (ints, distinct, in ``[0, n)``) -> int64 array; ``InputError`` on ``--views``, or on
    ``--protocol`` when the views are the protocol's own (``table`` names them), not the user's."""
    if table is not None:
        bad = [int(v) for v in views if not 0 <= int(v) < n]
        if bad:
            raise InputError(f"{table} {tuple(int(v) for v in views)} index the train split, which has {n} "
                             f"images (view {bad[0]} is past its end); choose views with --views",
                             field="--protocol")
    if isinstance(views, (str, bytes)) or not hasattr(views, "__iter__"):
        raise InputError(f"expected a list of view indices, got {views!r}", field="--views")
    out = []
    for v in views:
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
            raise InputError(f"view index {v!r} is not an integer", field="--views")
        v = int(v)
        if not 0 <= v < n:
            raise InputError(f"view index {v} out of range [0, {n}) ({what})", field="--views")
        if v in out:
            raise InputError(f"duplicate view index {v}", field="--views")
        out.append(v)
    if not out:
        raise InputError("empty view list", field="--views")
    return np.asarray(out, np.int64)


def _n_views(n_views, default: int, n_max: int, what: str, protocol: str = "") -> int:
    if n_views is None:
        if not 1 <= default <= n_max:   # the protocol's own count: --n-views was not given
            raise InputError(f"protocol {protocol!r} takes {default} views, and the scene has {n_max} {what}; "
                             f"choose fewer with --n-views" if n_max else
                             f"protocol {protocol!r} needs {what}, and the scene has none", field="--protocol")
        n_views = default
    if isinstance(n_views, (bool, np.bool_)) or not isinstance(n_views, numbers.Integral):
        raise InputError(f"expected an integer, got {n_views!r}", field="--n-views")
    if not 1 <= int(n_views) <= n_max:
        raise InputError(f"must be in [1, {n_max}] ({what}), got {n_views}", field="--n-views")
    return int(n_views)


def _test_split(scene: Scene, protocol: str) -> np.ndarray:
    test = scene.splits["test"]
    if test.size == 0:
        raise InputError(
            f"scene {scene.name!r} has no test split; use protocol 'llff' or 'views'", field="--protocol"
        )
    return test


def _evenly(n: int, k: int) -> np.ndarray:
    """``k`` of ``n`` positions spread evenly: ``round(linspace(0, n - 1, k))`` (half to even), int64 ``(k,)``."""
    return np.round(np.linspace(0, n - 1, k)).astype(np.int64)


def spread_views(idx, k: int, field: str = "--test-views") -> np.ndarray:
    """``k`` of the view indices ``idx (n,)`` spread evenly over them, the first and the last included:
    ``idx[round(linspace(0, n - 1, k))]`` (rounding half to even), int64 ``(k,)`` in ``idx``'s order; all of
    ``idx`` when ``k`` is ``n``.

    Example:
        >>> spread_views(np.arange(100, 300), 5).tolist()
        [100, 150, 200, 249, 299]

    Raises:
        InputError: naming ``field`` when ``k`` is below 1 or above ``n``, or ``idx`` is empty.
    """
    idx = np.asarray(idx, dtype=np.int64).reshape(-1)
    if idx.size == 0:
        raise InputError(f"there are no views to choose {k!r} from", field=field)
    if isinstance(k, bool) or not isinstance(k, numbers.Integral) or not 1 <= k <= idx.size:
        raise InputError(f"expected a number of views from 1 to the {idx.size} there are, got {k!r}", field=field)
    return idx[_evenly(idx.size, int(k))]


def _is_split_scene(scene: Scene) -> bool:
    """Blender-style: views index the train split (an object scene with a val or test split)."""
    return scene.kind == "object" and (scene.splits["val"].size > 0 or scene.splits["test"].size > 0)


def fewshot_split(scene: Scene, protocol: str = "extreme", views=None, n_views=None, seed: int = 0):
    """Training and test view indices of a few-shot protocol (see the module docstring for each one).

    Args:
        scene: a loaded :class:`Scene`.
        protocol: one of :data:`PROTOCOLS`.
        views: explicit view indices (``'views'``; overrides the table for ``'extreme'``).
        n_views: number of training views (``'llff'``, ``'spread'``: default 3; ``'random8'``: default 8).
        seed: seed of ``'random8'``.

    Returns:
        ``(train_idx, test_idx)``: int64 arrays of indices into the scene's arrays; disjoint.

    Raises:
        InputError: naming ``--protocol``, ``--views`` or ``--n-views``.
    """
    if protocol not in PROTOCOLS:
        raise InputError(f"unknown protocol {protocol!r}; expected one of {', '.join(PROTOCOLS)}",
                         field="--protocol")
    if views is not None and protocol not in ("extreme", "views"):
        raise InputError(f"explicit views are not used by protocol {protocol!r} (give --views without "
                         "--protocol; in Python, protocol 'views')", field="--views")
    if n_views is not None and protocol not in ("llff", "random8", "spread"):
        raise InputError(f"not used by protocol {protocol!r} (only 'llff', 'random8' and 'spread')",
                         field="--n-views")
    train_split = scene.splits["train"]
    n_train = int(train_split.size)

    if protocol == "extreme":
        if views is None:
            key = scene.name.lower()
            if key not in EXTREME_VIEWS:
                raise InputError(
                    f"no Extreme views known for scene {scene.name!r} (known: {', '.join(sorted(EXTREME_VIEWS))}); "
                    "pass views explicitly",
                    field="--views",
                )
            train = train_split[_as_view_list(EXTREME_VIEWS[key], n_train, "indices into the train split",
                                              table=f"the extreme protocol's views for {scene.name!r}")]
            return train, _test_split(scene, protocol)
        train = train_split[_as_view_list(views, n_train, "indices into the train split")]
        return train, _test_split(scene, protocol)
    if protocol == "infonerf4":
        train = train_split[_as_view_list(INFONERF4_VIEWS, n_train, "indices into the train split",
                                          table="the infonerf4 protocol's views")]
        return train, _test_split(scene, protocol)
    if protocol == "random8":
        k = _n_views(n_views, DEFAULT_N_VIEWS[protocol], n_train, "train-split views", protocol)
        rng = np.random.default_rng(seed)
        pick = rng.choice(n_train, size=k, replace=False)
        return train_split[np.asarray(pick, np.int64)], _test_split(scene, protocol)
    if protocol == "spread":
        test = _test_split(scene, protocol)
        k = _n_views(n_views, DEFAULT_N_VIEWS[protocol], n_train, "train-split views", protocol)
        return train_split[_evenly(n_train, k)], test
    if protocol == "all":
        if n_train == 0:
            raise InputError(f"scene {scene.name!r} has an empty train split", field="--protocol")
        return train_split.copy(), scene.splits["test"].copy()

    n = scene.n_images
    idx = np.arange(n, dtype=np.int64)
    if protocol == "llff":
        test = idx[idx % LLFF_HOLDOUT == 0]
        rest = idx[idx % LLFF_HOLDOUT != 0]
        if rest.size == 0:
            raise InputError(f"scene {scene.name!r} has too few images ({n}) for the LLFF hold-out", field="--protocol")
        k = _n_views(n_views, DEFAULT_N_VIEWS[protocol], int(rest.size), "non-held-out images", protocol)
        return rest[_evenly(int(rest.size), k)], test

    # protocol == "views"
    if views is None:
        raise InputError("protocol 'views' needs explicit view indices", field="--views")
    if _is_split_scene(scene):
        train = train_split[_as_view_list(views, n_train, "indices into the train split")]
        return train, _test_split(scene, protocol)
    train = _as_view_list(views, n, "indices into all images")
    test = np.setdiff1d(scene.splits["test"], train)
    if test.size == 0:
        test = np.setdiff1d(idx, train)
    if test.size == 0:
        raise InputError("every image is a training view; nothing left to test on", field="--views")
    return train, test
