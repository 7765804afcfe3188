"""``senerf-view``: a finished ``senerf-fit`` run, live in the browser (a `viser <https://viser.studio>`_ server).

Each browser tab has a render thread: moving frames (``moving_scale`` times the still frame's sides) while its
camera moves, the still frame (the fit's pixel count times ``scale**2``, at the tab's aspect) once no camera message
has come for ``still_after`` seconds.  The panel picks the iteration (the teacher or a student) and RGB or depth,
shows or hides the training cameras (frustums with their photos) and the shown iteration's pseudo views (orange,
with their reliability masks ``iter_K/pseudo/mask_XXX.png``), and saves keyframes that ``senerf-render --path``
replays.

Convention: viser's camera is camera-to-world with OpenCV axes (+z forward, +y down) and a vertical field of view,
so it is the scene's c2w as it is (:func:`camera_from_viser`); the viewer's world frame is the scene's.
"""

from __future__ import annotations

import argparse
import errno
import math
import shlex
import socket
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from senerf import __version__
from senerf.cliargs import (THREADS_HELP, OneLineParser, check_device, command_main, console_entry, float_flag,
                            int_flag, set_threads, threads_flag)
from senerf.errors import InputError

__all__ = ["ViewSettings", "camera_from_viser", "frame_size", "render_frame", "Viewer", "main", "console"]

PROG = "senerf-view"
_TRAIN_COLOUR, _PSEUDO_COLOUR = (40, 90, 220), (255, 140, 0)


@dataclass(frozen=True)
class ViewSettings:
    """How the viewer trades resolution for speed.

    Attributes:
        scale: the still frame has the fit's pixel count times ``scale**2``.
        moving_scale: a moving frame's sides are this fraction of the still frame's (0.5: a quarter of its pixels).
        still_after: seconds without a camera message after which the camera counts as stopped.
    """

    scale: float = 1.0
    moving_scale: float = 0.5
    still_after: float = 0.15


def camera_from_viser(wxyz, position, fov: float, width: int, height: int):
    """viser's camera as an OpenCV ``c2w (4, 4)`` float64 and the pinhole intrinsics of a ``width`` x ``height``
    image of it (square pixels, principal point at the centre).

    Args:
        wxyz: ``(4,)`` the camera-to-world rotation as a quaternion (w first), +z forward, +y down (viser's
            ``CameraHandle.wxyz``).
        position: ``(3,)`` the camera centre in the world.
        fov: the vertical field of view in radians.
    """
    import viser.transforms as vt

    from senerf.geometry import Intrinsics

    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = vt.SO3(np.asarray(wxyz, dtype=np.float64)).normalize().as_matrix(), position
    f = 0.5 * height / math.tan(0.5 * fov)
    return c2w, Intrinsics(f, f, width / 2.0, height / 2.0, int(width), int(height))


def frame_size(aspect: float, pixels: float) -> tuple[int, int]:
    """``(width, height)`` of about ``pixels`` pixels with ``width / height`` near ``aspect``, each side >= 8."""
    height = max(8, round(math.sqrt(pixels / aspect)))
    return max(8, round(height * aspect)), height


def render_frame(run, c2w, intrinsics, show: str = "rgb") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame as the viewer shows it: ``image (H, W, 3)`` uint8 (the colour, or with ``show='depth'`` the
    depth colour-mapped as senerf-render's depth frames), ``z_depth (H, W)`` and ``acc (H, W)`` float32
    (:meth:`senerf.fitted.FittedRun.render` of ``c2w (4, 4)``)."""
    from senerf.train import depth_to_color
    from senerf.train.evaluate import to_uint8

    out = run.render(c2w, intrinsics)
    z, acc = out["z_depth"][0], out["acc"][0]
    if show == "depth":
        return depth_to_color(z, acc, background=1.0 if run.model.eval_background == "white" else 0.0), z, acc
    return to_uint8(out["rgb"][0]), z, acc


def _fov(k) -> float:
    """The vertical field of view (radians) of intrinsics ``k``."""
    return 2.0 * math.atan(0.5 * k.height / k.fy)


def _look_distance(scene, c2w: np.ndarray) -> float:
    """How far in front of ``c2w (4, 4)`` the scene's centre is (what the viewer orbits): the point the scene's
    cameras look at, or for a forward-facing capture NeRF's spiral focus depth."""
    from senerf.geometry import closest_point_to_axes, spiral_focus_depth

    if scene.near is not None and scene.far is not None:
        return spiral_focus_depth(scene.near, scene.far)
    try:
        depth = float((closest_point_to_axes(scene.c2w) - c2w[:3, 3]) @ c2w[:3, 2])
    except ValueError:   # parallel axes: no such point
        depth = 0.0
    return depth if depth > 0 else 1.0


class _Client:
    """One browser tab: its render thread shows a moving frame after each camera message, the still frame once
    the camera stops."""

    def __init__(self, viewer: "Viewer", client):
        self.viewer, self.client = viewer, client
        self.wake, self.closed, self.still_due = threading.Event(), False, False
        client.camera.on_update(lambda camera: self.wake.set())
        threading.Thread(target=self._loop, name=f"{PROG}-tab-{client.client_id}", daemon=True).start()

    def _loop(self) -> None:
        while not self.closed:
            moved = self.wake.wait(self.viewer.settings.still_after)
            if self.closed or not (moved or self.still_due):
                continue
            self.wake.clear()
            self.still_due = moved
            try:
                image, depth = self.viewer.frame(self.client, still=not moved)
                if not self.closed:   # still frames lossless, moving ones small
                    self.client.scene.set_background_image(image, format="jpeg" if moved else "png",
                                                           jpeg_quality=80, depth=depth)
            except Exception:   # a render that failed (a GPU out of memory): say so, keep serving
                traceback.print_exc()
                print(f"{PROG}: a frame failed to render (traceback above)", file=sys.stderr)


class Viewer:
    """A running viewer of ``run`` (a :class:`senerf.fitted.FittedRun`) on ``host:port``.

    Raises:
        InputError: ``port`` is taken on ``host`` (naming ``--port``).
    """

    def __init__(self, run, settings: ViewSettings = ViewSettings(), host: str = "127.0.0.1", port: int = 8080):
        import viser

        _check_port(host, port)
        self.settings, self.runs, self.run = settings, {run.iteration: run}, run
        self.lock, self.clients, self.keyframes, self.pseudo = threading.Lock(), {}, [], []
        cams = run.cameras
        k = cams.intrinsics[int(cams.train[0])]
        self.pixels = k.width * k.height * settings.scale ** 2
        start = int(cams.test[0] if len(cams.test) else cams.train[0])   # every tab opens at the first test view
        self.start, self.start_fov = cams.c2w[start], _fov(cams.intrinsics[start])
        self.server = server = viser.ViserServer(host=host, port=port, label=f"{PROG}: {run.scene.name}",
                                                 verbose=False)
        gui = server.gui
        gui.configure_theme(show_share_button=False)   # the share button tunnels the scene through viser's server
        self.show_cameras = gui.add_checkbox("Cameras", True, hint="the training (blue) and pseudo (orange) views")
        self.show_cameras.on_update(lambda e: self._show_cameras())
        self._scene_frame()
        names = {k: f"{k}: teacher" if k == 0 else f"{k}: student" for k in run.finished}
        self.iteration_menu = gui.add_dropdown("Iteration", tuple(names.values()), initial_value=names[run.iteration])
        self.iteration_menu.on_update(lambda e: self.set_iteration(int(self.iteration_menu.value.split(":")[0])))
        self.show_mode = gui.add_dropdown("Show", ("rgb", "depth"), initial_value="rgb")
        self.show_mode.on_update(lambda e: self.redraw())
        self.path_file = gui.add_text("Camera path file", str(Path(run.folder).resolve() / "camera_path.json"))
        gui.add_button("Add keyframe").on_click(lambda e: self.add_keyframe(e.client))
        gui.add_button("Save camera path").on_click(lambda e: self.save_path(e.client))
        self._pseudo_frustums()
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)

    @property
    def address(self) -> str:
        """``http://host:port/`` the viewer serves."""
        return f"http://{self.server.get_host()}:{self.server.get_port()}/"

    def _scene_frame(self) -> None:
        """The scene's up axis, the view every tab opens at and the training frustums."""
        from senerf.geometry import default_up
        from senerf.train.evaluate import to_uint8

        run, scene = self.run, self.run.scene
        self.server.scene.set_up_direction(default_up(scene.c2w[run.train_idx]))
        look = _look_distance(scene, self.start)
        initial = self.server.initial_camera
        initial.position, initial.look_at = self.start[:3, 3], self.start[:3, 3] + look * self.start[:3, 2]
        initial.up, initial.fov = -self.start[:3, 1], self.start_fov
        centres = scene.c2w[:, :3, 3]
        gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.diag(np.full(len(centres), np.inf))
        self.frustum_scale = min(0.1 * look, float(np.median(gaps.min(axis=1)))) if len(centres) > 1 \
            else 0.1 * look   # small beside the cameras' spacing: a forward-facing capture's are close together
        self.frustums = []
        for i in run.train_idx:
            self.frustums.append(self._frustum(f"/train/{int(i)}", scene.c2w[int(i)], scene.intrinsics_all[int(i)],
                                               _TRAIN_COLOUR, to_uint8(scene.rgb[int(i)])))

    def _frustum(self, name: str, c2w, k, colour, image):
        """A frustum of the camera ``c2w`` with intrinsics ``k``, its ``image (H, W, 3)`` uint8 (or None)
        subsampled to at most 160 pixels a side."""
        import viser.transforms as vt

        if image is not None:
            step = max(1, -(-max(image.shape[:2]) // 160))
            image = image[::step, ::step]
        return self.server.scene.add_camera_frustum(
            name, fov=_fov(k), aspect=k.width / k.height, scale=self.frustum_scale, thickness=2.0,
            thickness_units="screen", color=colour, image=image, wxyz=vt.SO3.from_matrix(c2w[:3, :3]).wxyz,
            position=c2w[:3, 3], visible=self.show_cameras.value)

    def _show_cameras(self) -> None:
        for handle in self.frustums + self.pseudo:
            handle.visible = self.show_cameras.value

    def _pseudo_frustums(self) -> None:
        """The pseudo views the shown iteration's student was distilled from (none for the teacher)."""
        import imageio.v3 as iio

        run = self.run
        for handle in self.pseudo:
            handle.remove()
        self.pseudo = []
        if run.iteration == 0:
            return
        c2w, ks = run.pseudo_cameras(run.iteration)
        for j, (pose, k) in enumerate(zip(c2w, ks)):
            mask = Path(run.folder) / f"iter_{run.iteration}" / "pseudo" / f"mask_{j:03d}.png"
            image = np.asarray(iio.imread(mask))[..., :3] if mask.is_file() else None
            self.pseudo.append(self._frustum(f"/pseudo/{j}", pose, k, _PSEUDO_COLOUR, image))

    def _connect(self, client) -> None:
        self.clients[client.client_id] = _Client(self, client)

    def _disconnect(self, client) -> None:
        tab = self.clients.pop(client.client_id, None)
        if tab is not None:
            tab.closed = True
            tab.wake.set()

    def camera(self, client, still: bool):
        """``(c2w (4, 4), intrinsics)`` of ``client``'s camera at the still or the moving resolution."""
        cam = client.camera
        width, height = frame_size(cam.aspect, self.pixels * (1.0 if still else self.settings.moving_scale ** 2))
        return camera_from_viser(cam.wxyz, cam.position, cam.fov, width, height)

    def frame(self, client, still: bool) -> tuple[np.ndarray, np.ndarray]:
        """``client``'s camera rendered: ``image (H, W, 3)`` uint8 and the depth ``(H, W)`` float32 viser
        composites the frustums with (far where the field is empty)."""
        c2w, k = self.camera(client, still)
        with self.lock:
            image, z, acc = render_frame(self.run, c2w, k, self.show_mode.value)
        return image, np.where(acc > 0.5, z, 1e3).astype(np.float32)

    def redraw(self) -> None:
        """Render every tab again (the iteration or the colouring changed)."""
        for tab in list(self.clients.values()):
            tab.wake.set()

    def set_iteration(self, iteration: int) -> None:
        """Show the field of a finished ``iteration`` (loaded once, then kept) and its pseudo views."""
        with self.lock:
            if iteration not in self.runs:
                self.runs[iteration] = self.run.at_iteration(iteration)
            self.run = self.runs[iteration]
        self._pseudo_frustums()
        self.redraw()

    def add_keyframe(self, client) -> None:
        """Keep ``client``'s camera (its pose, vertical field of view and still frame size) as a keyframe."""
        c2w, k = self.camera(client, still=True)
        self.keyframes.append((c2w, k))
        client.add_notification(f"Keyframe {len(self.keyframes)}", "added to the camera path", auto_close_seconds=3)

    def save_path(self, client) -> Path | None:
        """Write the keyframes (each at the first one's image size) to the file named in the panel and print the
        command that replays them; a problem is shown in the browser and nothing is written."""
        from senerf.camerapath import write_camera_path
        from senerf.geometry import Intrinsics

        if not self.keyframes:
            client.add_notification("No keyframes", "add the cameras of the path first", color="red")
            return None
        w, h = self.keyframes[0][1].size[::-1]
        ks = [Intrinsics(k.fy * h / k.height, k.fy * h / k.height, w / 2.0, h / 2.0, w, h) for _, k in self.keyframes]
        path = Path(self.path_file.value).expanduser()
        try:
            write_camera_path(path, np.stack([c for c, _ in self.keyframes]), ks)
        except OSError as exc:
            client.add_notification("Camera path not saved", f"{path}: {exc.strerror or exc}", color="red")
            return None
        command = shlex.join(["senerf-render", str(self.run.folder), "--path", str(path)])
        print(f"{PROG}: {len(ks)} keyframes saved to {path}; replay them with: {command}", flush=True)
        client.add_notification("Camera path saved", command, auto_close_seconds=10)
        return path

    def stop(self) -> None:
        """Stop the render threads and the server."""
        for tab in list(self.clients.values()):
            tab.closed = True
            tab.wake.set()
        self.server.stop()


def _check_port(host: str, port: int) -> None:
    """An :class:`InputError` naming ``--port`` when ``port`` cannot be bound on ``host`` (viser would otherwise
    move to the next free port unasked)."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as exc:
            raise InputError(f"cannot listen on {host}:{port} ({exc.strerror or exc}); choose another with --port"
                             f"{' or --host' if exc.errno != errno.EADDRINUSE else ''}", field="--port") from None


def build_parser() -> argparse.ArgumentParser:
    """The ``senerf-view`` argument parser (errors raise :class:`InputError`)."""
    p = OneLineParser(prog=PROG, description="Look at a finished senerf-fit run in the browser, live.",
                      epilog="Serves until Ctrl-C. Exit status: 130 stopped, 2 bad input, 1 internal error.")
    p.add_argument("run", type=Path, help="a senerf-fit output folder (its --out)")
    p.add_argument("--iteration", type=int_flag("--iteration", allow_zero=True), default=None,
                   help="the iteration shown first (default: the last; 0 = the teacher)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int_flag("--port", maximum=65535), default=8080, help="port (default 8080)")
    p.add_argument("--scale", type=float_flag("--scale", positive=True, maximum=8.0), default=1.0,
                   help="the still frame's pixels are the fit's times scale squared (default 1)")
    p.add_argument("--moving-scale", type=float_flag("--moving-scale", positive=True, maximum=1.0), default=0.5,
                   help="a moving frame's sides as a fraction of the still frame's (default 0.5)")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--threads", type=threads_flag(), default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def _run(args) -> int:
    from senerf.fitted import load_run

    device = check_device(args.device)
    set_threads(args.threads)
    _check_port(args.host, args.port)   # before the run is loaded
    run = load_run(args.run, args.iteration, device)
    from senerf.fields.ckernel import warn_without_kernel

    warn_without_kernel(run.model, device)   # the pure-PyTorch twin renders several times slower
    viewer = Viewer(run, ViewSettings(args.scale, args.moving_scale), args.host, args.port)
    try:
        print(f"{PROG}: {run.scene.name}, iteration {run.iteration} of {list(run.finished)}: open {viewer.address} "
              "(Ctrl-C stops)", flush=True)
        while True:
            time.sleep(3600)
    finally:
        viewer.stop()


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-view``; returns the exit status (130 stopped by Ctrl-C, 2 bad input, 1 internal)."""
    return command_main(PROG, lambda a: _run(build_parser().parse_args(a)), argv, "viewer stopped")


def console() -> None:
    """The ``senerf-view`` console script: :func:`main` through :func:`senerf.cliargs.console_entry`."""
    console_entry(main)


if __name__ == "__main__":  # pragma: no cover
    console()
