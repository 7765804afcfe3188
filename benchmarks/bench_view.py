"""Benchmark of ``senerf-view``: the frame rate while the camera moves and the time to the still frame.

Run (the lego Extreme fit of 100x100 images; the fit is made first if the folder holds none)::

    senerf-fit /work/shared/data/nerf_synthetic/lego --downscale 4 --protocol extreme --preset fast \\
        --out /tmp/bench_lego_fast
    python benchmarks/bench_view.py /tmp/bench_lego_fast

A stand-in browser tab (a camera that orbits the scene, sending camera messages at ``--hz``) is connected to a
:class:`senerf.viewer.Viewer`, so the frames go through the viewer's own render thread, its ``frame`` and its
``set_background_image`` call (only the websocket and the browser are left out).  Reported:

- the moving frames shown per second while the camera moves for ``--seconds`` (target: >= 10 fps);
- the time from the last camera message to the still frame (100x100 on a square canvas) being sent, which
  includes the viewer's ``still_after`` wait (target: <= 1 s);
- the render time of one moving and one still frame (``Viewer.frame`` called directly, median of 9).

Targets (issue #37): >= 10 fps moving, a still 100x100 frame within 1 s of the camera stopping, on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import math
import time
import types

import numpy as np


def _tab(c2w: np.ndarray, fov: float, aspect: float):
    """A stand-in for viser's ClientHandle: a camera, its update callbacks, and a scene that records the
    frames sent to it as ``(time, width, height, format)``."""
    from scipy.spatial.transform import Rotation

    sent, callbacks = [], []
    camera = types.SimpleNamespace(fov=fov, aspect=aspect, on_update=callbacks.append)

    def pose(c):
        x, y, z, w = Rotation.from_matrix(c[:3, :3]).as_quat()
        camera.wxyz, camera.position = np.array([w, x, y, z]), c[:3, 3].copy()
        for cb in callbacks:
            cb(camera)
    scene = types.SimpleNamespace(set_background_image=lambda image, format, **k: sent.append(
        (time.monotonic(), image.shape[1], image.shape[0], format)))
    pose(c2w)
    return types.SimpleNamespace(camera=camera, scene=scene, client_id=0, sent=sent, pose=pose)


def main() -> None:
    from senerf.cliargs import set_threads, short_openmp_waits

    short_openmp_waits()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", help="a finished senerf-fit run folder")
    p.add_argument("--seconds", type=float, default=5.0, help="how long the camera moves")
    p.add_argument("--hz", type=float, default=60.0, help="camera messages per second while it moves")
    p.add_argument("--moving-scale", type=float, default=0.5)
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=int, default=None)
    args = p.parse_args()
    set_threads(args.threads)

    import torch

    import senerf
    from senerf.geometry import orbit_path
    from senerf.viewer import ViewSettings, Viewer

    run = senerf.load_run(args.run, device=args.device)
    k = run.cameras.intrinsics[int(run.train_idx[0])]
    fov = 2.0 * math.atan(0.5 * k.height / k.fy)
    path = orbit_path(run.cameras.c2w[run.train_idx], max(2, int(args.seconds * args.hz)))
    viewer = Viewer(run, ViewSettings(moving_scale=args.moving_scale), port=0)
    try:
        tab = _tab(path[0], fov, k.width / k.height)
        for name, still in (("moving", False), ("still", True)):
            viewer.frame(tab, still)
            times = []
            for _ in range(9):
                t0 = time.perf_counter()
                viewer.frame(tab, still)
                times.append(time.perf_counter() - t0)
            w, h = viewer.camera(tab, still)[1].size[::-1]
            print(f"{name} frame {w}x{h}: {1e3 * np.median(times):.1f} ms to render (median of 9)")
        viewer._connect(tab)   # the viewer's render thread for this tab, as for a browser
        time.sleep(1.0)
        tab.sent.clear()
        t_start = time.monotonic()
        for i, c2w in enumerate(path):   # camera messages at --hz
            time.sleep(max(0.0, t_start + i / args.hz - time.monotonic()))
            tab.pose(c2w)
        t_stop = time.monotonic()
        deadline = t_stop + 5.0
        while not any(f[3] == "png" and f[0] > t_stop for f in tab.sent) and time.monotonic() < deadline:
            time.sleep(0.005)
        moving = [f for f in tab.sent if f[3] == "jpeg" and f[0] <= t_stop]
        still = [f for f in tab.sent if f[3] == "png" and f[0] > t_stop]
    finally:
        viewer.stop()
    fps = len(moving) / (t_stop - t_start)
    print(f"while moving ({args.hz:g} camera messages/s for {t_stop - t_start:.1f} s): {len(moving)} frames of "
          f"{moving[0][1]}x{moving[0][2]} = {fps:.1f} fps (target >= 10): {'met' if fps >= 10 else 'NOT met'}")
    if still:
        wait = still[0][0] - t_stop
        print(f"still {still[0][1]}x{still[0][2]} frame sent {wait:.2f} s after the last camera message (waits "
              f"{viewer.settings.still_after:g} s; target <= 1 s): {'met' if wait <= 1.0 else 'NOT met'}")
    else:
        print("no still frame within 5 s of the camera stopping: NOT met")
    print(f"host: {torch.get_num_threads()} torch threads, device {args.device}, field {run.model.field}, "
          f"{run.model.n_samples} samples per ray, iteration {run.iteration}")


if __name__ == "__main__":
    main()
