"""Protocol names, their senerf-fit flags, the published view lists, the image size read from the files, and the
grid of runs: run keys, senerf-fit arguments, scene kinds and each scene's downscale."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from senerf.bench.protocols import (METHODS, PRESETS, SUITE, RunSpec, discover_scenes, expand_specs, native_size,
                                    parse_protocol)
from senerf.config import PRESETS as FIT_PRESETS
from senerf.errors import InputError


@pytest.mark.parametrize("name, canonical, downscale, size", [
    ("synthetic-extreme3@100", "synthetic-extreme3@100", 8, (100, 100)),
    ("synthetic-extreme3", "synthetic-extreme3@800", 1, (800, 800)),
    ("synthetic-infonerf4@200", "synthetic-infonerf4@200", 4, (200, 200)),
    ("synthetic-random8", "synthetic-random8@400", 2, (400, 400)),
    ("llff3@504x378", "llff3@504x378", 8, (378, 504)),
    ("llff9@1008x756", "llff9@1008x756", 4, (756, 1008)),
    ("dtu3@192", "dtu3@192", 2, (192, 192)),
    ("dtu9", "dtu9@384", 1, (384, 384)),
])
def test_parse_protocol(name, canonical, downscale, size):
    p = parse_protocol(name)
    assert (p.name, p.downscale, p.size) == (canonical, downscale, size)


@pytest.mark.parametrize("bad", ["extreme3@100", "synthetic-extreme3@300", "synthetic-extreme3@abc",
                                 "synthetic-extreme3@0", "llff3@500x378", "llff3@504x379", "llff3@100",
                                 "llff3@8064x6048", "synthetic-extreme3@²", "llff3@5０4x378", "llff3@504x³",
                                 "dtu3@100", "dtu3@504x378", "dtu12@192"])
def test_parse_protocol_refuses_names_that_are_no_protocol(bad):
    with pytest.raises(InputError, match="^protocol: "):
        parse_protocol(bad)


def test_fit_flags_follow_the_contract():
    assert parse_protocol("synthetic-extreme3@100").fit_flags() == ["--protocol", "extreme", "--downscale", "8"]
    assert parse_protocol("synthetic-infonerf4@400").fit_flags(4.0) == ["--protocol", "infonerf4", "--downscale", "4"]
    assert parse_protocol("synthetic-random8").fit_flags() == ["--protocol", "random8", "--downscale", "2"]
    assert parse_protocol("llff6@504x378").fit_flags() == ["--protocol", "llff", "--n-views", "6", "--downscale", "8"]
    assert parse_protocol("dtu6@192").fit_flags() == ["--protocol", "dtu", "--n-views", "6", "--downscale", "2"]


def test_dtu_protocols_fix_the_first_views_of_dtus_list():
    # the DTU protocol: train views 25, 22, 28, 40, 44, 48, 0, 8, 13 in that order, the first 3, 6 or 9
    order = (25, 22, 28, 40, 44, 48, 0, 8, 13)
    assert [tuple(parse_protocol(f"dtu{n}@192").views("scan24")) for n in (3, 6, 9)] == [order[:n] for n in (3, 6, 9)]


def test_view_lists_are_reference_section_5():
    # REFERENCE.md section 5: "chair 26,31,32; drums 3,9,14; ficus 12,36,56; hotdog 31,33,48; lego 0,1,51;
    # materials 47,63,73; ship 36,55,66; mic 35,65,82"; InfoNeRF [26, 86, 2, 55]; the scene name in any case
    extreme = parse_protocol("synthetic-extreme3@100")
    published = {"chair": (26, 31, 32), "drums": (3, 9, 14), "ficus": (12, 36, 56), "hotdog": (31, 33, 48),
                 "lego": (0, 1, 51), "materials": (47, 63, 73), "ship": (36, 55, 66), "mic": (35, 65, 82)}
    assert {scene: extreme.views(scene.upper()) for scene in published} == published
    assert extreme.views("my_capture") is None
    assert tuple(parse_protocol("synthetic-infonerf4").views("anything")) == (26, 86, 2, 55)
    assert parse_protocol("synthetic-random8").views("lego") is None and parse_protocol("llff3").views("fern") is None


def test_downscale_for_images_of_another_size():
    assert parse_protocol("synthetic-extreme3@100").downscale_for((400, 400)) == 4
    assert parse_protocol("synthetic-extreme3@100").downscale_for((300, 300)) == 3
    assert parse_protocol("llff3@504x378").downscale_for((3024, 4032)) == 8
    for name, size in (("synthetic-extreme3@200", (100, 100)), ("llff3@504x378", (3000, 3000))):   # up, aspect
        with pytest.raises(InputError, match="cannot be downscaled"):
            parse_protocol(name).downscale_for(size)


def test_native_size_reads_the_first_frame_or_poses_bounds(blender_factory, llff_scene, tmp_path):
    assert native_size(blender_factory(tmp_path, side=400)) == (400, 400)
    assert native_size(llff_scene) == (3024, 4032)


def _blender(root, doc, name="lego"):
    d = root / name
    (d / "train").mkdir(parents=True)
    (d / "transforms_train.json").write_text(doc)
    return d


@pytest.mark.parametrize("doc, field", [("{", "frames[0].file_path"), ('{"frames": []}', "frames[0].file_path"),
                                        ('{"frames": [{}]}', "frames[0].file_path")])
def test_native_size_of_a_broken_transforms_file_names_it(tmp_path, doc, field):
    d = _blender(tmp_path, doc)
    message = f"{d / 'transforms_train.json'}: {field}: cannot read the image size"
    with pytest.raises(InputError, match="^" + re.escape(message)):
        native_size(d)


def test_native_size_names_the_image_it_cannot_read(tmp_path):
    d = _blender(tmp_path, json.dumps({"frames": [{"file_path": "./train/r_0"}]}))
    with pytest.raises(InputError, match=rf"^{d / 'train' / 'r_0.png'}: cannot read the image size"):
        native_size(d)
    e = _blender(tmp_path, json.dumps({"frames": [{"file_path": "train/r_0.jpg"}]}), name="jpg")
    with pytest.raises(InputError, match=rf"^{e / 'train' / 'r_0.jpg'}: "):
        native_size(e)


@pytest.mark.parametrize("content", [b"not a numpy file", np.zeros((0, 17)), np.full((2, 17), np.nan)],
                         ids=["garbage", "no-rows", "nan"])
def test_native_size_of_a_broken_poses_bounds_names_hwf(tmp_path, content):
    d = tmp_path / "fern"
    d.mkdir()
    path = d / "poses_bounds.npy"
    path.write_bytes(content) if isinstance(content, bytes) else np.save(path, content)
    with pytest.raises(InputError, match=rf"^{path}: hwf: "):
        native_size(d)


def test_a_scene_of_zero_sized_images_is_refused_naming_it(tmp_path):
    d = tmp_path / "fern"
    d.mkdir()
    np.save(d / "poses_bounds.npy", np.zeros((2, 17)))
    with pytest.raises(InputError, match=rf"^{d}: protocol: images of 0x0 cannot be downscaled to 504x378"):
        expand_specs([str(d)], ["llff3@504x378"], ["baseline"], ["fast"], [0])


def test_expand_grid_keys_unique_and_kinds_matched(blender_scene, llff_scene):
    specs = expand_specs([str(blender_scene), str(llff_scene)], ["synthetic-extreme3@100", "llff3@504x378"],
                         list(METHODS), ["fast", "balanced"], [0, 1], iterations=2)
    # lego gets only the synthetic protocol, fern only LLFF: 2 scenes x 1 protocol x every method x 2 presets x 2 seeds
    assert len(specs) == 2 * 1 * len(METHODS) * 2 * 2
    assert len({s.key() for s in specs}) == len(specs)
    assert {(s.scene, s.protocol) for s in specs} == {("lego", "synthetic-extreme3@100"), ("fern", "llff3@504x378")}
    assert all(s.iterations == (0 if s.method == "baseline" else 2) for s in specs)
    args = specs[0].fit_args("/o")
    assert args[0] == str(blender_scene) and args[-3:] == ["--out", "/o", "--overwrite"]
    assert args[args.index("--preset") + 1] == specs[0].preset


def test_iterations_default_to_each_presets_own():
    specs = expand_specs(["/nowhere/lego"], ["synthetic-extreme3@100"], ["baseline", "senerf"], list(PRESETS), [0],
                         check_scenes=False)
    assert PRESETS == tuple(FIT_PRESETS)
    assert {(s.method, s.preset): s.iterations for s in specs} == {
        **{("baseline", p): 0 for p in PRESETS}, **{("senerf", p): FIT_PRESETS[p].iterations for p in PRESETS}}


def test_fit_args_carry_the_method_steps_and_seed():
    spec = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "senerf-threshold-fixed", "fast", 3, 2, "cpu", 20)
    assert spec.key() == "lego|synthetic-extreme3@100|senerf-threshold-fixed|fast|seed3|K2|cpu|steps20"
    assert spec.dirname() == "lego__synthetic-extreme3@100__senerf-threshold-fixed__fast__seed3__K2__cpu__steps20"
    assert spec.fit_args("/o") == ["/d/lego", "--protocol", "extreme", "--downscale", "8", "--iterations", "2",
                                   "--threshold", "fixed", "--preset", "fast", "--seed", "3", "--device", "cpu",
                                   "--steps", "20", "--out", "/o", "--overwrite"]
    plain = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "baseline", "fast", 0, 0)
    assert plain.key() == "lego|synthetic-extreme3@100|baseline|fast|seed0|K0|cpu"
    assert "--steps" not in plain.fit_args("/o")


def test_downscale_comes_from_the_files(tmp_path, llff_scene, blender_factory):
    half = blender_factory(tmp_path / "copy", side=400)          # a pre-downscaled copy
    (spec,) = expand_specs([str(half)], ["synthetic-extreme3@100"], ["baseline"], ["fast"], [0])
    assert spec.fit_args("/o")[3:5] == ["--downscale", "4"]
    (fern,) = expand_specs([str(llff_scene)], ["llff3@504x378"], ["baseline"], ["fast"], [0])
    assert fern.fit_args("/o")[5:7] == ["--downscale", "8"]
    (unchecked,) = expand_specs(["/nowhere/lego"], ["synthetic-extreme3@100"], ["baseline"], ["fast"], [0],
                                check_scenes=False)   # a dry run without the data: the factor for 800x800 files
    assert unchecked.fit_args("/o")[3:5] == ["--downscale", "8"]


def test_suite_discovers_every_scene_of_a_data_folder_and_notes_what_it_leaves_out(data_tree):
    scenes, notes = discover_scenes(data_tree)
    assert [str(s.relative_to(data_tree)) for s in scenes] == ["nerf_synthetic/lego", "nerf_synthetic/mic",
                                                               "nerf_llff_data/fern", "dtu/scan24"]
    assert sorted(n.split(": ", 1)[1].split(",")[0] for n in notes) == ["left out", "left out"]
    assert any("mine: left out, no published Extreme views" in n for n in notes)
    assert any("notes: left out, not a dtu scene folder" in n for n in notes)
    specs = expand_specs([str(s) for s in scenes], list(SUITE), ["senerf"], ["fast"], [0, 1, 2])
    assert sorted({(s.scene, s.protocol, s.downscale) for s in specs}) == [
        ("fern", "llff3@504x378", 8.0), ("lego", "synthetic-extreme3@100", 8.0),
        ("mic", "synthetic-extreme3@100", 8.0), ("scan24", "dtu3@192", 2.0)]
    assert len(specs) == 12 and {s.seed for s in specs} == {0, 1, 2}
    with pytest.raises(InputError, match="no scene folders in nerf_synthetic/, nerf_llff_data/ or dtu/"):
        discover_scenes(data_tree / "dtu")
    with pytest.raises(InputError, match="--data: data folder not found"):
        discover_scenes(data_tree / "missing")


def test_expand_refuses_unknown_names_and_folders(blender_scene, blender_factory, tmp_path):
    grid = (["synthetic-extreme3@100"], ["senerf"], ["fast"], [0])
    for protocols, methods, presets, field in ((grid[0], grid[1], ["turbo"], "preset"),
                                               (grid[0], ["magic"], grid[2], "method"),
                                               (["nope@1"], grid[1], grid[2], "protocol")):
        with pytest.raises(InputError, match=f"^{field}: unknown {field} "):
            expand_specs([str(blender_scene)], protocols, methods, presets, [0])
    with pytest.raises(InputError, match=rf"^{tmp_path}: not a Blender"):
        expand_specs([str(tmp_path)], *grid)
    small = blender_factory(tmp_path, name="lego400", side=400)     # which scene cannot give the protocol's size
    with pytest.raises(InputError, match=rf"^{small}: protocol: images of 400x400 cannot be downscaled to 800x800"):
        expand_specs([str(small)], ["synthetic-extreme3@800"], ["baseline"], ["fast"], [0])
