"""The DDA ray marcher (``kernels/render.cl``), its camera and frame encoding."""

from sdfserver.render.camera import Camera, RenderLimits, RenderOptions, parse_view
from sdfserver.render.encode import FORMATS, encode_frame, format_from_accept
from sdfserver.render.renderer import Frame, Pick, Renderer

__all__ = ["FORMATS", "Camera", "Frame", "Pick", "RenderLimits", "RenderOptions", "Renderer",
           "encode_frame", "format_from_accept", "parse_view"]
