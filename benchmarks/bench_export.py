"""Benchmark of ``senerf-export --mesh``: the mesh of a dense fit of the procedural demo scene against its exact mesh.

Run: ``python benchmarks/bench_export.py --out /tmp/bench-export`` (writes the demo scene, fits its 20 training
views, teacher only, balanced preset, then exports and measures), or ``--run RUN`` to reuse such a fit.

Figures:
* the export's wall-clock time (``senerf-export RUN --mesh mesh.ply``, default flags), against the 60 s target;
* the Chamfer distance of the exported mesh to the exact procedural mesh (:func:`senerf.procedural.scene.
  build_scene`): both surfaces sampled uniformly by area (200 000 points each, seeded), the symmetric mean
  ``(mean d(fit -> exact) + mean d(exact -> fit)) / 2``, as a percent of the exact mesh's extent (the largest side
  of its bounding box; the diagonal's percent is printed too), against the 2 % target.  "seen" repeats it with
  the exact samples that a training camera sees (the bottom of the ground disc and faces hidden inside other
  objects are never photographed, so no fit can place them);
* the vertex colours' mean absolute error (0-255 scale) against the exact shaded colour (the procedural
  renderer's, view-independent) of the nearest seen exact surface sample;
* the same geometry figures at other density levels and with ``--components largest`` (one density grid, re-meshed).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

SAMPLES = 200_000


def chamfer(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Mean nearest distance from points ``a (n, 3)`` to ``b (m, 3)`` and from ``b`` to ``a``."""
    return float(cKDTree(b).query(a)[0].mean()), float(cKDTree(a).query(b)[0].mean())


def seen(scene, points: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: a point is the first hit of the ray from some camera centre in ``c2w (k, 4, 4)`` towards it."""
    out = np.zeros(len(points), bool)
    for pose in c2w:
        d = points - pose[:3, 3]
        dist = np.linalg.norm(d, axis=1)
        loc, ray, _ = scene.intersector.intersects_location(np.broadcast_to(pose[:3, 3], d.shape), d / dist[:, None],
                                                            multiple_hits=False)
        first = np.full(len(points), np.inf)
        first[ray] = np.linalg.norm(loc - pose[:3, 3], axis=1)
        out |= first >= dist - 1e-4
    return out


def exact_colours(scene, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(n, 3)`` the procedural renderer's colour of surface ``points (n, 3)`` on the mesh ``faces (n,)``."""
    from senerf.procedural.render import RayHits, shade

    n = len(points)
    hits = RayHits(np.ones(n, bool), np.zeros(n), points, scene.mesh.face_normals[faces], scene.face_object[faces],
                   faces)
    return shade(scene, hits)


def main() -> None:
    import trimesh

    import senerf
    from senerf.export import default_level, density_grid, grid_mesh, main as export, mesh_region
    from senerf.procedural.export import make_demo_scene
    from senerf.procedural.scene import SceneConfig, build_scene

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("bench-export"))
    p.add_argument("--run", type=Path, help="reuse this fit of the demo scene (all its training views)")
    p.add_argument("--seed", type=int, default=0, help="the demo scene's seed (the one --run was fitted on)")
    p.add_argument("--levels", default="0.25,0.5,1,2,4", help="multiples of the default level to re-mesh at")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    run = args.run
    if run is None:
        scene_dir = make_demo_scene(args.out / "scene", seed=args.seed, overwrite=True)
        run = args.out / "run"
        t0 = time.perf_counter()
        senerf.fit(scene_dir, run, protocol="all", iterations=0, test_views=4, overwrite=True)
        print(f"fit: {time.perf_counter() - t0:.0f} s")
    mesh_file = args.out / "mesh.ply"
    t0 = time.perf_counter()
    assert export([str(run), "--mesh", str(mesh_file), "--overwrite", "--quiet"]) == 0
    seconds = time.perf_counter() - t0

    exact = build_scene(SceneConfig(seed=args.seed))
    fitted = senerf.load_run(run)
    ref, ref_faces = trimesh.sample.sample_surface(exact.mesh, SAMPLES, seed=1)
    is_seen = seen(exact, ref, fitted.cameras.c2w[fitted.train_idx])
    ref_seen = ref[is_seen]
    lo, hi = exact.mesh.bounds
    side, diag = float((hi - lo).max()), float(np.linalg.norm(hi - lo))

    def measure(mesh) -> dict:
        pts = trimesh.sample.sample_surface(mesh, SAMPLES, seed=2)[0]
        acc, comp = chamfer(pts, ref)
        comp_seen = chamfer(pts, ref_seen)[1]
        return dict(faces=len(mesh.faces), accuracy=acc, completeness=comp, chamfer=(acc + comp) / 2,
                    chamfer_pct_side=50 * (acc + comp) / side, chamfer_pct_diag=50 * (acc + comp) / diag,
                    chamfer_seen_pct_side=50 * (acc + comp_seen) / side)

    mesh = trimesh.load(mesh_file)
    rows = {"export": dict(seconds=seconds, **measure(mesh))}
    nearest = cKDTree(ref_seen).query(mesh.vertices)[1]
    truth = exact_colours(exact, ref_seen, ref_faces[is_seen]) * 255
    colour_error = float(np.abs(mesh.visual.vertex_colors[:, :3] - truth[nearest]).mean())
    box = mesh_region(fitted.model)
    grid = density_grid(fitted.density, *box, 256)
    base = default_level(fitted.model)
    for f in (float(x) for x in args.levels.split(",")):
        for comp in ("all", "largest"):
            rows[f"level {f:g}x ({base * f:.3g}) {comp}"] = measure(grid_mesh(grid, *box, base * f, comp))
    print(f"exact mesh extent: largest side {side:.3f}, diagonal {diag:.3f}; {len(ref_seen)} of {SAMPLES} exact "
          "samples seen by a training camera")
    print(f"{'':34s} {'faces':>8s} {'acc':>7s} {'comp':>7s} {'CD % side':>9s} {'CD % diag':>9s} {'seen % side':>11s}")
    for name, r in rows.items():
        print(f"{name:34s} {r['faces']:8d} {r['accuracy']:7.4f} {r['completeness']:7.4f} {r['chamfer_pct_side']:9.2f} "
              f"{r['chamfer_pct_diag']:9.2f} {r['chamfer_seen_pct_side']:11.2f}")
    print(f"export: {seconds:.1f} s (target < 60 s); Chamfer {rows['export']['chamfer_pct_side']:.2f} % of the "
          f"largest side (target < 2 %); vertex colour error {colour_error:.1f} / 255")
    summary = dict(run=str(run), side=side, diagonal=diag, colour_error=colour_error, rows=rows)
    (args.out / "bench_export.json").write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
