"""Radiance fields, ray sampling and volume rendering (torch); ``__all__`` is the public API (see DESIGN.md)."""

from .base import RadianceField, contract_unit, field_coords, trunc_exp, uncontract_unit
from .encoding import anneal_weights, positional_encoding, sh_encoding
from .kplanes import KPlanesField
from .nerf import NeRFField
from .occupancy import OccupancyGrid
from .render import EMPTY_ACC, bin_distortion, contraction_box, render_image, render_rays, volume_render
from .sampling import bin_fractions, contracted_bins, linear_bins, ndc_points, ndc_rays, ndc_t_to_depth, ray_bins

__all__ = [
    "RadianceField", "KPlanesField", "NeRFField", "OccupancyGrid",
    "contract_unit", "uncontract_unit", "field_coords",
    "bin_fractions", "linear_bins", "contracted_bins", "ray_bins", "ndc_points", "ndc_rays", "ndc_t_to_depth",
    "volume_render", "render_rays", "render_image", "contraction_box", "bin_distortion", "EMPTY_ACC",
    "sh_encoding", "positional_encoding", "anneal_weights", "trunc_exp",
]
