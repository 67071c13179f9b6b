#version 450
// One step of the mip pyramid (level l from level l - 1), one invocation per texel of level
// l; with BACKWARD its transpose (dL/d level l - 1 += P^T dL/d level l), one invocation per
// texel of level l - 1, a gather: no atomics, the same result on every run.
// Per axis, a level of extent n gives m = max(1, n / 2) texels; texel j is the mean of the
// finer level over its footprint: taps 2j, 2j + 1, 2j + 2 with weights
//   n == 1: (1, 0, 0)    n even: (1/2, 1/2, 0)    n = 2m + 1: (m - j, m, j + 1) / (2m + 1)
// Texel layout: ((image * H + y) * W + x) * channels + c from the level's first float
// (`images` = texture batch x faces; CHANNELS floats per texel, a define).

layout(local_size_x = 64) in;

layout(std430, binding = 0) buffer Levels { float levels[]; };
// the same buffer through a buffer texture (R32F, unit LEVELS_UNIT) for the reads of the
// other level: llvmpipe's texel fetches are several times faster than its storage-buffer
// loads (a pass reads one level and writes another: no texel read is written in it)
layout(binding = LEVELS_UNIT) uniform samplerBuffer levels_view;

uniform int fine_first;     // first float of level l - 1
uniform int coarse_first;   // first float of level l
uniform ivec2 fine_size;    // (W, H) of level l - 1
uniform ivec2 coarse_size;  // (W, H) of level l
uniform int images;
const int channels = CHANNELS;   // a define: the channel loops unroll

float tap_weight(int n, int j, int k) {  // weight of finer texel 2j + k in coarse texel j
    if (n == 1) return k == 0 ? 1.0 : 0.0;
    if (n % 2 == 0) return k < 2 ? 0.5 : 0.0;
    int m = n / 2;
    float w = k == 0 ? float(m - j) : (k == 1 ? float(m) : float(j + 1));
    return w / float(2 * m + 1);
}

void main() {
    uint gid = gl_GlobalInvocationID.x;
    // the taps' weights and first floats are found once, then used for every channel (the
    // same products and sums, in the same order, as per channel)
#ifndef BACKWARD
    int W = coarse_size.x, H = coarse_size.y;
    if (gid >= uint(images * W * H)) return;
    int x = int(gid) % W, y = (int(gid) / W) % H, image = int(gid) / (W * H);
    float wy[3], wx[3];
    int at[3][3];
    for (int k = 0; k < 3; ++k) {
        wy[k] = tap_weight(fine_size.y, y, k);
        wx[k] = tap_weight(fine_size.x, x, k);
    }
    for (int ky = 0; ky < 3; ++ky)
        for (int kx = 0; kx < 3; ++kx)
            at[ky][kx] = fine_first + ((image * fine_size.y + 2 * y + ky) * fine_size.x
                                       + 2 * x + kx) * channels;
    for (int c = 0; c < channels; ++c) {
        float v = 0.0;
        for (int ky = 0; ky < 3; ++ky) {
            if (wy[ky] == 0.0) continue;
            float row = 0.0;
            for (int kx = 0; kx < 3; ++kx) {
                if (wx[kx] == 0.0) continue;
                row += wx[kx] * texelFetch(levels_view, at[ky][kx] + c).x;
            }
            v += wy[ky] * row;
        }
        levels[coarse_first + int(gid) * channels + c] = v;
    }
#else
    int W = fine_size.x, H = fine_size.y;
    if (gid >= uint(images * W * H)) return;
    int x = int(gid) % W, y = (int(gid) / W) % H, image = int(gid) / (W * H);
    // coarse texels y / 2 - 1 + r, x / 2 - 1 + q (r, q = 0, 1); weight 0: not read
    float wy[2], wx[2];
    int cys[2], cxs[2];
    for (int r = 0; r < 2; ++r) {
        int cy = y / 2 - 1 + r, ky = y - 2 * cy;
        wy[r] = (cy < 0 || cy >= coarse_size.y || ky < 0 || ky > 2) ? 0.0
                                                                    : tap_weight(H, cy, ky);
        cys[r] = cy;
        int cx = x / 2 - 1 + r, kx = x - 2 * cx;
        wx[r] = (cx < 0 || cx >= coarse_size.x || kx < 0 || kx > 2) ? 0.0
                                                                    : tap_weight(W, cx, kx);
        cxs[r] = cx;
    }
    for (int c = 0; c < channels; ++c) {
        float v = 0.0;
        for (int r = 0; r < 2; ++r) {
            if (wy[r] == 0.0) continue;
            float row = 0.0;
            for (int q = 0; q < 2; ++q) {
                if (wx[q] == 0.0) continue;
                row += wx[q] * texelFetch(levels_view, coarse_first + ((image * coarse_size.y
                                          + cys[r]) * coarse_size.x + cxs[q]) * channels + c).x;
            }
            v += wy[r] * row;
        }
        levels[fine_first + int(gid) * channels + c] += v;
    }
#endif
}
