#version 450
// The deterministic texture backward's last step on the GPU: each 64-bit fixed-point sum
// (include/fixed_point.glsl's words: low, high, two's complement) to the float32
// round(q 2^-k), one invocation per value. In double (core since GL 4.0): q = hi 2^32 + lo
// is rounded once to 53 bits by the addition (hi 2^32 and lo are exact), the scaling by a
// power of two is exact, and the conversion to float rounds to nearest even (GLSL 4.50,
// section 4.1.10): the same float as NumPy's int64 -> float64 -> ldexp -> float32.

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Words { uint words[]; };
layout(std430, binding = 1) writeonly buffer Values { float values[]; };

uniform uint first_value;  // this dispatch's values: first_value .. first_value + n_values - 1
uniform uint n_values;
uniform double unit;       // 2^-k (a double uniform: exact)

void main() {
    if (gl_GlobalInvocationID.x >= n_values) return;
    uint n = first_value + gl_GlobalInvocationID.x;
    uint lo = words[2u * n], hi = words[2u * n + 1u];
    double q = double(int(hi)) * 4294967296.0lf + double(lo);
    values[n] = float(q * unit);   // not ldexp: llvmpipe gives ldexp(0, -k) != 0
}
