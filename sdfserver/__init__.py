"""sdfserver: chunked voxel worlds resident on an OpenCL device, with exact Manhattan distance fields."""

__version__ = "0.1.0"
