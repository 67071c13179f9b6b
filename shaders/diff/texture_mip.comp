#version 450
// One step of the mip pyramid (level l from level l - 1), one invocation per texel of level
// l; with BACKWARD its transpose (dL/d level l - 1 += P^T dL/d level l), one invocation per
// texel of level l - 1, a gather: no atomics, the same result on every run.
// Per axis, a level of extent n gives m = max(1, n / 2) texels; texel j is the mean of the
// finer level over its footprint: taps 2j, 2j + 1, 2j + 2 with weights
//   n == 1: (1, 0, 0)    n even: (1/2, 1/2, 0)    n = 2m + 1: (m - j, m, j + 1) / (2m + 1)
// Texel layout: ((image * H + y) * W + x) * channels + c from the level's first float
// (`images` = texture batch x faces).

layout(local_size_x = 64) in;

layout(std430, binding = 0) buffer Levels { float levels[]; };

uniform int fine_first;     // first float of level l - 1
uniform int coarse_first;   // first float of level l
uniform ivec2 fine_size;    // (W, H) of level l - 1
uniform ivec2 coarse_size;  // (W, H) of level l
uniform int images;
uniform int channels;

float tap_weight(int n, int j, int k) {  // weight of finer texel 2j + k in coarse texel j
    if (n == 1) return k == 0 ? 1.0 : 0.0;
    if (n % 2 == 0) return k < 2 ? 0.5 : 0.0;
    int m = n / 2;
    float w = k == 0 ? float(m - j) : (k == 1 ? float(m) : float(j + 1));
    return w / float(2 * m + 1);
}

void main() {
    uint gid = gl_GlobalInvocationID.x;
#ifndef BACKWARD
    int W = coarse_size.x, H = coarse_size.y;
    if (gid >= uint(images * W * H)) return;
    int x = int(gid) % W, y = (int(gid) / W) % H, image = int(gid) / (W * H);
    for (int c = 0; c < channels; ++c) {
        float v = 0.0;
        for (int ky = 0; ky < 3; ++ky) {
            float wy = tap_weight(fine_size.y, y, ky);
            if (wy == 0.0) continue;
            int fy = 2 * y + ky;
            float row = 0.0;
            for (int kx = 0; kx < 3; ++kx) {
                float wx = tap_weight(fine_size.x, x, kx);
                if (wx == 0.0) continue;
                int fx = 2 * x + kx;
                row += wx * levels[fine_first + ((image * fine_size.y + fy) * fine_size.x + fx)
                                    * channels + c];
            }
            v += wy * row;
        }
        levels[coarse_first + int(gid) * channels + c] = v;
    }
#else
    int W = fine_size.x, H = fine_size.y;
    if (gid >= uint(images * W * H)) return;
    int x = int(gid) % W, y = (int(gid) / W) % H, image = int(gid) / (W * H);
    for (int c = 0; c < channels; ++c) {
        float v = 0.0;
        for (int cy = y / 2 - 1; cy <= y / 2; ++cy) {
            if (cy < 0 || cy >= coarse_size.y) continue;
            int ky = y - 2 * cy;
            if (ky < 0 || ky > 2) continue;
            float wy = tap_weight(H, cy, ky);
            if (wy == 0.0) continue;
            float row = 0.0;
            for (int cx = x / 2 - 1; cx <= x / 2; ++cx) {
                if (cx < 0 || cx >= coarse_size.x) continue;
                int kx = x - 2 * cx;
                if (kx < 0 || kx > 2) continue;
                float wx = tap_weight(W, cx, kx);
                if (wx == 0.0) continue;
                row += wx * levels[coarse_first + ((image * coarse_size.y + cy) * coarse_size.x
                                                   + cx) * channels + c];
            }
            v += wy * row;
        }
        levels[fine_first + int(gid) * channels + c] += v;
    }
#endif
}
