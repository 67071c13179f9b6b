// A clip-space vertex in the frame of a pixel centre n (in NDC) of a size.x x size.y
// viewport: v' = ((W/2)(x - w n_x), (H/2)(y - w n_y), w). The cross product of two such
// vertices is the row of the edge function through them (Olano & Greer 1997), in window
// pixels relative to the centre (docs/differentiable.md, "Antialias").
vec3 frame_vertex(vec4 p, vec2 n, ivec2 size) {
    return vec3((p.x - p.w * n.x) * (0.5 * float(size.x)),
                (p.y - p.w * n.y) * (0.5 * float(size.y)), p.w);
}
