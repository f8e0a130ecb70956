"""sdfserver: chunked voxel worlds resident on an OpenCL device, with exact Manhattan distance fields.

Importing any part of sdfserver first registers the CPU OpenCL runtimes the project installs
(``sdfserver/cpu_runtimes.py``): that must happen before pyopencl is imported and before the first
OpenCL call of the process, and many modules import pyopencl.
"""

from sdfserver.cpu_runtimes import register_cpu_runtimes

register_cpu_runtimes()

__version__ = "0.1.0"
