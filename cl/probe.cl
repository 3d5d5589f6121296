/* The backend probe (twin of kernels/probe.py): a tiny kernel that a device must build, with the
 * shared helpers of common.cl prepended, and run right before it is offered. float64, as facet
 * sampling needs. */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

__kernel void probe(__global const double *values, __global double *out, int n)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    double x = values[i];
    out[i] = x * x + 0.5 * x + 1.0;
}
