"""Radiance fields, ray sampling and volume rendering (torch); ``__all__`` is the public API (see DESIGN.md)."""

from .base import RadianceField, trunc_exp
from .encoding import anneal_weights, positional_encoding, sh_encoding
from .kplanes import KPlanesField
from .nerf import NeRFField
from .occupancy import OccupancyGrid
from .render import EMPTY_ACC, render_image, render_rays, volume_render
from .sampling import ndc_rays, ndc_t_to_depth, stratified_bins

__all__ = [
    "RadianceField", "KPlanesField", "NeRFField", "OccupancyGrid",
    "stratified_bins", "ndc_rays", "ndc_t_to_depth",
    "volume_render", "render_rays", "render_image", "EMPTY_ACC",
    "sh_encoding", "positional_encoding", "anneal_weights", "trunc_exp",
]
