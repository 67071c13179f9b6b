#version 450
// The deterministic texture backward's last step on the GPU: each 64-bit fixed-point sum
// (include/fixed_point.glsl's words: low, high, two's complement, plus 2^31) to the float32
// round(q 2^-k), four values per invocation (wide loads and stores: half the time of one),
// the words read through a buffer texture over them (RGBA32UI, unit WORDS_UNIT: llvmpipe's
// texel fetches are several times faster than its storage-buffer loads).
// In double (core since GL 4.0): q = hi 2^32 + lo is rounded once to 53 bits by the
// addition (hi 2^32 and lo are exact), the scaling by a power of two is exact, and the
// conversion to float rounds to nearest even (GLSL 4.50, section 4.1.10): the same float
// as NumPy's int64 -> float64 -> ldexp -> float32.

layout(local_size_x = 64) in;

layout(binding = WORDS_UNIT) uniform usamplerBuffer words;   // two values a texel
layout(std430, binding = 1) writeonly buffer Values { vec4 values[]; };

uniform uint first_quad;  // this dispatch's values: 4 first_quad .. 4 (first_quad + n_quads) - 1
uniform uint n_quads;
uniform double unit;      // 2^-k (a double uniform: exact)

// not ldexp: llvmpipe gives ldexp(0, -k) != 0 in double
float value(uvec2 w) {
    // the low word's bias 2^31 off: w.x - 2^31 as a signed int is w.x with its top bit flipped
    return float((double(int(w.y)) * 4294967296.0lf + double(int(w.x ^ 0x80000000u))) * unit);
}

void main() {
    if (gl_GlobalInvocationID.x >= n_quads) return;
    uint n = first_quad + gl_GlobalInvocationID.x;
    uvec4 a = texelFetch(words, int(2u * n)), b = texelFetch(words, int(2u * n + 1u));
    values[n] = vec4(value(a.xy), value(a.zw), value(b.xy), value(b.zw));
}
