#version 450
// Antialias, pass 2: the blend. One invocation per listed pixel P (pixel_list: the pixels
// of the candidate pairs, sorted; every other pixel keeps its colour); its four incident pair
// records (pass 1, antialias_pairs.comp) give the partners whose colour it takes and the
// weights alpha_k; with CONVEX the weights are scaled by s = 1 / max(1, sum alpha_k) (so the
// output is a convex combination of P and its neighbours), else s = 1:
//   out[li] = c_P + s sum_k alpha_k (c_k - c_P),      scale_out[li] = s,
// and P's four incident records go to incident_out[4 li + k] (zero where the neighbour is
// outside the image), the compact input of the backward (antialias_backward.comp).
// Colours are those of the listed pixels only, color[li] (a partner's place in the list
// found by binary search: every pixel of a candidate pair is listed). Pass 1 writes the
// records of the candidate pairs only (ids differ, as the host lists them: the floats of
// rast's id channel compare unequal) and nobody clears the others: a pair whose ids are
// equal reads as no blend.

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Color { float color[]; };
layout(std430, binding = 1) readonly buffer Records { uvec4 records[]; };
layout(std430, binding = 2) writeonly buffer Out { float out_color[]; };
layout(std430, binding = 3) writeonly buffer Scale { float scale_out[]; };
layout(std430, binding = 4) readonly buffer PixelList { uint pixel_list[]; };
layout(std430, binding = 5) writeonly buffer Incident { uvec4 incident_out[]; };
layout(std430, binding = 6) readonly buffer Rast { vec4 rast[]; };

uniform uint n_list;
uniform ivec2 size;          // (W, H)
uniform int n_channels;

// The pixels P takes colour from and their weights (partner = P, alpha = 0 when unused):
// slot 0 its right neighbour, 1 its left, 2 the one above, 3 the one below; rec: the four
// records (those of the pairs (P, right), (left, P), (P, above), (below, P)).
void incident(uint i, out uint partner[4], out float alpha[4], out uvec4 rec[4]) {
    uint W = uint(size.x), H = uint(size.y), hw = W * H;
    uint pix = i % hw, y = pix / W, x = pix % W;
    for (int k = 0; k < 4; ++k) { partner[k] = i; alpha[k] = 0.0; rec[k] = uvec4(0u); }
    float id = rast[i].w;
    if (x + 1u < W && rast[i + 1u].w != id) rec[0] = records[2u * i];
    if (x > 0u && rast[i - 1u].w != id) rec[1] = records[2u * (i - 1u)];
    if (y + 1u < H && rast[i + W].w != id) rec[2] = records[2u * i + 1u];
    if (y > 0u && rast[i - W].w != id) rec[3] = records[2u * (i - W) + 1u];
    if ((rec[0].x & 3u) == 1u) { partner[0] = i + 1u; alpha[0] = 0.5 - uintBitsToFloat(rec[0].w); }
    if ((rec[1].x & 3u) == 2u) { partner[1] = i - 1u; alpha[1] = uintBitsToFloat(rec[1].w) - 0.5; }
    if ((rec[2].x & 3u) == 1u) { partner[2] = i + W; alpha[2] = 0.5 - uintBitsToFloat(rec[2].w); }
    if ((rec[3].x & 3u) == 2u) { partner[3] = i - W; alpha[3] = uintBitsToFloat(rec[3].w) - 0.5; }
}

// The place of pixel i in the sorted pixel_list (i is listed).
uint place(uint i) {
    uint lo = 0u, hi = n_list - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (pixel_list[mid] < i) lo = mid + 1u; else hi = mid;
    }
    return lo;
}

void main() {
    uint li = gl_GlobalInvocationID.x;
    if (li >= n_list) return;
    uint i = pixel_list[li];
    uint partner[4];
    float alpha[4];
    uvec4 rec[4];
    incident(i, partner, alpha, rec);
    for (int k = 0; k < 4; ++k) partner[k] = partner[k] == i ? li : place(partner[k]);
    for (int k = 0; k < 4; ++k) incident_out[4u * li + uint(k)] = rec[k];
    float total = (alpha[0] + alpha[1]) + (alpha[2] + alpha[3]);
#ifdef CONVEX
    float s = total > 1.0 ? 1.0 / total : 1.0;
#else
    float s = 1.0;
#endif
    scale_out[li] = s;
    uint C = uint(n_channels);
    for (uint c = 0u; c < C; ++c) {
        float own = color[li * C + c];
        float sum = 0.0;
        for (int k = 0; k < 4; ++k) sum += alpha[k] * (color[partner[k] * C + c] - own);
        out_color[li * C + c] = own + s * sum;
    }
}
