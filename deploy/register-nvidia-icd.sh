#!/bin/sh
# Register NVIDIA's OpenCL driver with the ICD loader (images often ship the library without this file).
set -eu
mkdir -p /etc/OpenCL/vendors
echo libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd
echo "registered: /etc/OpenCL/vendors/nvidia.icd"
