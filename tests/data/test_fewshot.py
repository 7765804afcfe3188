"""Tests of senerf/data/fewshot.py: the few-shot protocols and their input checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from senerf.data import EXTREME_VIEWS, Scene, fewshot_split
from senerf.errors import InputError
from senerf.geometry import Intrinsics


def make_scene(n: int, splits: dict, kind: str = "object", name: str = "lego") -> Scene:
    """A 1x1-pixel scene with ``n`` views (only indices matter here)."""
    k = Intrinsics(1.0, 1.0, 0.5, 0.5, 1, 1)
    return Scene(
        name=name, root=Path(name), rgb=np.zeros((n, 1, 1, 3), np.float32), alpha=None, intrinsics=k,
        intrinsics_all=(k,) * n, c2w=np.broadcast_to(np.eye(4), (n, 4, 4)).copy(), splits=splits, kind=kind,
        image_paths=tuple(Path(f"{i}.png") for i in range(n)),
    )


def blender_like(name="lego", n_train=100, n_val=10, n_test=20) -> Scene:
    # Arrays: val first here (not train), so "index into the train split" differs from "index into all".
    n = n_train + n_val + n_test
    return make_scene(n, {"val": np.arange(n_val), "train": np.arange(n_val, n_val + n_train),
                          "test": np.arange(n_val + n_train, n)}, name=name)


def test_extreme_lego_indexes_train_split():
    scene = blender_like()
    train, test = fewshot_split(scene, "extreme")
    assert train.tolist() == [10 + 0, 10 + 1, 10 + 51]  # lego 0, 1, 51 into the train split (offset 10)
    assert test.tolist() == list(range(110, 130))


def test_extreme_scene_name_is_case_insensitive():
    assert fewshot_split(blender_like("Ship"), "extreme")[0].tolist() == [46, 65, 76]


def test_extreme_unknown_scene_needs_views():
    scene = blender_like("kitchen")
    with pytest.raises(InputError, match="kitchen") as info:
        fewshot_split(scene, "extreme")
    assert info.value.field == "--views"
    assert fewshot_split(scene, "extreme", views=[5, 2])[0].tolist() == [15, 12]


def test_real_lego_extreme(lego4):
    train, test = fewshot_split(lego4, "extreme")
    assert train.tolist() == [0, 1, 51]  # Blender arrays start with the train split
    assert test.tolist() == list(range(200, 400))


def test_infonerf4():
    assert fewshot_split(blender_like(), "infonerf4")[0].tolist() == [36, 96, 12, 65]


def test_random8_seeded_distinct_in_train_split():
    scene = blender_like()
    a, test = fewshot_split(scene, "random8", seed=3)
    b, _ = fewshot_split(scene, "random8", seed=3)
    c, _ = fewshot_split(scene, "random8", seed=4)
    assert a.tolist() == b.tolist() and a.tolist() != c.tolist()
    assert len(set(a.tolist())) == 8 and set(a.tolist()) <= set(range(10, 110))
    want = 10 + np.random.default_rng(3).choice(100, 8, replace=False)  # the documented draw
    assert a.tolist() == want.tolist()
    assert fewshot_split(scene, "random8", n_views=5)[0].size == 5


def test_llff_protocol_general_n():
    # 30 images: test = 0, 8, 16, 24; rest has 26 entries; linspace(0, 25, 4) = 0, 8.33, 16.67, 25
    # -> round 0, 8, 17, 25 -> rest = [1..7, 9..15, 17..23, 25..29] -> 1, 10, 20, 29.
    scene = make_scene(30, {"train": np.arange(30)}, kind="forward_facing")
    train, test = fewshot_split(scene, "llff", n_views=4)
    assert test.tolist() == [0, 8, 16, 24]
    assert train.tolist() == [1, 10, 20, 29]


def test_spread_protocol_by_hand():
    # train split = arrays 10..109 (100 views); linspace(0, 99, 3) = 0, 49.5, 99 -> round 0, 50 (49.5 to even),
    # 99 -> arrays 10, 60, 109; test = the test split, untouched
    train, test = fewshot_split(blender_like(), "spread")
    assert train.tolist() == [10, 60, 109] and test.tolist() == list(range(110, 130))
    # n_views 4: linspace(0, 99, 4) = 0, 33, 66, 99
    assert fewshot_split(blender_like(), "spread", n_views=4)[0].tolist() == [10, 43, 76, 109]
    with pytest.raises(InputError, match="no test split") as info:   # it never invents a hold-out
        fewshot_split(make_scene(5, {"train": np.arange(5)}, name="mine"), "spread")
    assert info.value.field == "--protocol"


def test_views_blender_into_train_split():
    train, test = fewshot_split(blender_like(), "views", views=[0, 99])
    assert train.tolist() == [10, 109] and test.tolist() == list(range(110, 130))


def test_views_llff_into_all_images_and_test_excludes_train():
    scene = make_scene(20, {"train": [i for i in range(20) if i % 8], "test": [0, 8, 16]}, kind="forward_facing")
    train, test = fewshot_split(scene, "views", views=[8, 3])
    assert train.tolist() == [8, 3] and test.tolist() == [0, 16]


def test_views_ngp_without_splits_tests_on_the_rest():
    scene = make_scene(5, {"train": np.arange(5)})
    train, test = fewshot_split(scene, "views", views=[1, 3])
    assert train.tolist() == [1, 3] and test.tolist() == [0, 2, 4]


@pytest.mark.parametrize("n_views", [None, 3, 6, 9])
def test_dtu_protocol_takes_the_published_views_in_order_and_tests_on_its_25(n_views):
    # RegNeRF's DTU split, written out by hand here: train 25, 22, 28 | 40, 44, 48 | 0, 8, 13.
    scene = make_scene(49, {"train": np.arange(49)}, kind="unbounded", name="scan24")
    train, test = fewshot_split(scene, "dtu", n_views=n_views)
    assert train.tolist() == [25, 22, 28, 40, 44, 48, 0, 8, 13][:n_views or 3]
    assert test.tolist() == [1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43, 45,
                             46, 47]
    with pytest.raises(InputError, match="must be in"):
        fewshot_split(scene, "dtu", n_views=10)


def test_all_protocol():
    train, test = fewshot_split(blender_like(), "all")
    assert train.tolist() == list(range(10, 110)) and test.tolist() == list(range(110, 130))


@pytest.mark.parametrize(
    "kwargs, field, problem",
    [
        (dict(protocol="extreme", views=[0, 100]), "--views", "out of range"),
        (dict(protocol="extreme", views=[-1]), "--views", "out of range"),
        (dict(protocol="views", views=[3, 3]), "--views", "duplicate"),
        (dict(protocol="views", views=[1.5]), "--views", "not an integer"),
        (dict(protocol="views", views=[]), "--views", "empty"),
        (dict(protocol="views"), "--views", "needs explicit"),
        (dict(protocol="views", views="1,2"), "--views", "list of view indices"),
        (dict(protocol="llff", views=[1]), "--views", "not used"),
        (dict(protocol="extreme", n_views=3), "--n-views", "not used"),
        (dict(protocol="llff", n_views=0), "--n-views", "must be in"),
        (dict(protocol="llff", n_views=200), "--n-views", "must be in"),
        (dict(protocol="random8", n_views=101), "--n-views", "must be in"),
        (dict(protocol="spread", n_views=101), "--n-views", "must be in"),
        (dict(protocol="spread", views=[1]), "--views", "not used"),
        (dict(protocol="fancy"), "--protocol", "unknown protocol"),
        (dict(protocol="dtu"), "--protocol", "the 49 images of a DTU scan"),
    ],
)
def test_bad_protocol_input(kwargs, field, problem):
    with pytest.raises(InputError) as info:
        fewshot_split(blender_like(), **kwargs)
    assert info.value.field == field and problem in info.value.problem


def test_protocol_needing_test_split_on_ngp_scene():
    scene = make_scene(5, {"train": np.arange(5)}, name="lego")
    with pytest.raises(InputError, match="no test split") as info:
        fewshot_split(scene, "extreme", views=[0])
    assert info.value.field == "--protocol"


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 80), frac=st.floats(0.0, 1.0))
def test_llff_protocol_properties(n, frac):
    # For any size: test is exactly the multiples of 8, train has n_views distinct non-test views in
    # increasing order, and the first and last non-test images are always used when n_views >= 2.
    scene = make_scene(n, {"train": np.arange(n)}, kind="forward_facing")
    n_rest = n - len(range(0, n, 8))
    k = 1 + int(frac * (n_rest - 1))
    train, test = fewshot_split(scene, "llff", n_views=k)
    assert test.tolist() == list(range(0, n, 8))
    assert len(train) == k and np.all(np.diff(train) > 0) and np.all(train % 8 != 0)
    if k >= 2:
        rest = [i for i in range(n) if i % 8]
        assert train[0] == rest[0] and train[-1] == rest[-1]


def test_a_protocols_own_views_or_count_past_the_train_split_name_the_protocol():
    # with no flag given, the protocol's own views or count are at fault, not --views or --n-views
    scene = blender_like(n_train=6, n_val=1, n_test=2)
    for protocol in ("extreme", "infonerf4", "random8"):
        with pytest.raises(InputError) as info:
            fewshot_split(scene, protocol)
        assert info.value.field == "--protocol", protocol
    with pytest.raises(InputError) as info:   # the user's own values still name the user's flags
        fewshot_split(scene, "extreme", views=[0, 7])
    assert info.value.field == "--views"
    with pytest.raises(InputError) as info:
        fewshot_split(scene, "random8", n_views=7)
    assert info.value.field == "--n-views"


@pytest.mark.parametrize("n_views", [2.0, True, "2", np.float64(2.0)])
def test_a_number_of_views_that_is_not_an_integer_is_refused(n_views):
    scene = make_scene(10, {"train": np.arange(10)}, kind="forward_facing")
    with pytest.raises(InputError) as info:
        fewshot_split(scene, "llff", n_views=n_views)
    assert info.value.field == "--n-views"
    assert fewshot_split(scene, "llff", n_views=np.int64(2))[0].tolist() == [1, 9]   # rest 1..7, 9: its ends


def test_protocol_all_refuses_an_empty_train_split():
    with pytest.raises(InputError) as info:
        fewshot_split(make_scene(3, {"test": [0, 1, 2]}), "all")
    assert info.value.field == "--protocol"
    train, test = fewshot_split(make_scene(3, {"train": [2], "test": [0, 1]}), "all")
    assert (train.tolist(), test.tolist()) == ([2], [0, 1])


def test_llff_holdout_of_a_single_image_is_refused():
    with pytest.raises(InputError) as info:
        fewshot_split(make_scene(1, {}, kind="forward_facing"), "llff")
    assert info.value.field == "--protocol"
    train, test = fewshot_split(make_scene(2, {}, kind="forward_facing"), "llff", n_views=1)   # 0 held out, 1 trains
    assert (train.tolist(), test.tolist()) == ([1], [0])


def test_views_covering_every_image_leave_nothing_to_test():
    scene = make_scene(3, {"test": [0]}, kind="forward_facing")
    with pytest.raises(InputError) as info:
        fewshot_split(scene, "views", views=[0, 1, 2])
    assert info.value.field == "--views"
    assert fewshot_split(scene, "views", views=[0, 1])[1].tolist() == [2]   # the test view trains: the rest tests
    assert fewshot_split(scene, "views", views=[1, 2])[1].tolist() == [0]


#: REFERENCE.md section 5, copied by hand: "chair 26,31,32; drums 3,9,14; ficus 12,36,56; hotdog 31,33,48;
#: lego 0,1,51; materials 47,63,73; ship 36,55,66; mic 35,65,82".
_REFERENCE_EXTREME = {"chair": (26, 31, 32), "drums": (3, 9, 14), "ficus": (12, 36, 56), "hotdog": (31, 33, 48),
                      "lego": (0, 1, 51), "materials": (47, 63, 73), "ship": (36, 55, 66), "mic": (35, 65, 82)}


def test_extreme_protocol_uses_the_reference_views_for_every_scene():
    # 100 train views after 10 val views, so index v -> 10 + v
    assert {k: tuple(v) for k, v in EXTREME_VIEWS.items()} == _REFERENCE_EXTREME
    for name, views in _REFERENCE_EXTREME.items():
        assert fewshot_split(blender_like(name), "extreme")[0].tolist() == [10 + v for v in views], name


@pytest.mark.parametrize("other", ["test", "val"])
def test_views_index_the_train_split_when_only_one_other_split_exists(other):
    # a nerfstudio file with train and test lists but no val list (or train and val only) is a split scene:
    # train split = 3, 4, 5, so view 0 is image 3
    scene = make_scene(6, {"train": [3, 4, 5], other: [0, 1, 2]})
    if other == "test":
        train, test = fewshot_split(scene, "views", views=[0, 2])
        assert train.tolist() == [3, 5] and test.tolist() == [0, 1, 2]
    else:
        with pytest.raises(InputError) as info:   # indexes the train split, then needs a test split
            fewshot_split(scene, "views", views=[0, 2])
        assert info.value.field == "--protocol"
