"""Protocol names, senerf-fit flags, run keys and grid expansion."""

from __future__ import annotations

import pytest

from senerf.bench.protocols import METHODS, get_method, parse_protocol, random_views
from senerf.bench.specs import expand_specs
from senerf.errors import InputError


@pytest.mark.parametrize("name, canonical, downscale, size", [
    ("synthetic-extreme3@100", "synthetic-extreme3@100", 8, (100, 100)),
    ("synthetic-extreme3", "synthetic-extreme3@800", 1, (800, 800)),
    ("synthetic-infonerf4@200", "synthetic-infonerf4@200", 4, (200, 200)),
    ("synthetic-random8", "synthetic-random8@400", 2, (400, 400)),
    ("llff3@504x378", "llff3@504x378", 8, (378, 504)),
    ("llff9@1008x756", "llff9@1008x756", 4, (756, 1008)),
])
def test_parse_protocol(name, canonical, downscale, size):
    p = parse_protocol(name)
    assert (p.name, p.downscale, p.size) == (canonical, downscale, size)


@pytest.mark.parametrize("bad", ["extreme3@100", "synthetic-extreme3@300", "synthetic-extreme3@abc",
                                 "llff3@500x378", "llff3@504x379", "llff3@100"])
def test_parse_protocol_rejects(bad):
    with pytest.raises(InputError):
        parse_protocol(bad)


def test_fit_flags_follow_the_contract():
    assert parse_protocol("synthetic-extreme3@100").fit_flags("lego", 0) == [
        "--protocol", "extreme", "--downscale", "8"]
    assert parse_protocol("synthetic-infonerf4@400").fit_flags("lego", 5) == [
        "--views", "26,86,2,55", "--downscale", "2"]
    assert parse_protocol("llff6@504x378").fit_flags("fern", 0) == [
        "--protocol", "llff", "--n-views", "6", "--downscale", "8"]
    assert get_method("baseline").fit_flags(3) == ["--iterations", "0"]
    assert get_method("senerf-threshold-fixed").fit_flags(2) == ["--iterations", "2", "--threshold", "fixed"]
    assert parse_protocol("synthetic-extreme3@100").views("lego", 0) == (0, 1, 51)


def test_random_views_seeded_distinct_and_in_range():
    a, b = random_views(100, 8, seed=3), random_views(100, 8, seed=3)
    assert a == b and len(set(a)) == 8 and all(0 <= v < 100 for v in a) and list(a) == sorted(a)
    assert random_views(100, 8, seed=4) != a
    flags = parse_protocol("synthetic-random8@400").fit_flags("lego", 3)
    assert flags[:2] == ["--views", ",".join(map(str, a))]


def test_expand_grid_keys_unique_and_kinds_matched(blender_scene, llff_scene):
    specs = expand_specs([str(blender_scene), str(llff_scene)],
                         ["synthetic-extreme3@100", "llff3@504x378"], list(METHODS), ["fast", "balanced"],
                         [0, 1], iterations=2)
    # lego gets only the synthetic protocol, fern only LLFF: 2 scenes x 1 protocol x 7 methods x 2 x 2
    assert len(specs) == 2 * 1 * len(METHODS) * 2 * 2
    assert len({s.key() for s in specs}) == len(specs)
    assert {(s.scene, s.protocol.split("@")[0]) for s in specs} == {("lego", "synthetic-extreme3"),
                                                                  ("fern", "llff3")}
    assert all(s.iterations == (0 if s.method == "baseline" else 2) for s in specs)
    args = specs[0].fit_args("/o")
    assert args[0] == str(blender_scene) and args[-3:] == ["--out", "/o", "--overwrite"]
    assert args[args.index("--preset") + 1] == specs[0].preset


def test_expand_rejects_bad_input(blender_scene, tmp_path):
    with pytest.raises(InputError):
        expand_specs([str(blender_scene)], ["synthetic-extreme3@100"], ["senerf"], ["turbo"], [0])
    with pytest.raises(InputError):
        expand_specs([str(blender_scene)], ["synthetic-extreme3@100"], ["magic"], ["fast"], [0])
    with pytest.raises(InputError):
        expand_specs([str(tmp_path)], ["synthetic-extreme3@100"], ["senerf"], ["fast"], [0])


def test_downscale_comes_from_the_files(tmp_path, llff_scene, blender_factory):
    half = blender_factory(tmp_path / "copy", side=400)          # a pre-downscaled copy
    (spec,) = expand_specs([str(half)], ["synthetic-extreme3@100"], ["baseline"], ["fast"], [0])
    args = spec.fit_args("/o")
    assert args[args.index("--downscale") + 1] == "4"
    (fern,) = expand_specs([str(llff_scene)], ["llff3@504x378"], ["baseline"], ["fast"], [0])
    assert fern.fit_args("/o")[fern.fit_args("/o").index("--downscale") + 1] == "8"
    assert parse_protocol("synthetic-extreme3@100").downscale_for((300, 300)) == 3.0
    with pytest.raises(InputError):
        parse_protocol("synthetic-extreme3@200").downscale_for((100, 100))   # no upscaling
    with pytest.raises(InputError):
        parse_protocol("llff3@504x378").downscale_for((3000, 3000))         # aspect differs
