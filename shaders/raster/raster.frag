#version 450 core
// Writes the requested barycentric targets. Window depth needs no output: the depth
// attachment (32-bit float, test LESS) holds gl_FragCoord.z.
//
// Host defines: OUT_PERSP, OUT_SCREEN, OUT_TRI_ID and PERSP_LOCATION, SCREEN_LOCATION,
// TRI_ID_LOCATION (the color attachment of each).

// INTERPOLATION (host define, multisampling): "centroid" or "sample", the auxiliary
// qualifier of the barycentric inputs (GLSL 4.50 section 4.5); empty: the pixel center.
#ifndef INTERPOLATION
#define INTERPOLATION
#endif

#ifdef OUT_PERSP
INTERPOLATION smooth in vec3 v_persp;
layout(location = PERSP_LOCATION) out vec3 out_persp;
#endif
#ifdef OUT_SCREEN
INTERPOLATION noperspective in vec3 v_screen;
layout(location = SCREEN_LOCATION) out vec3 out_screen;
#endif
#ifdef OUT_TRI_ID
// Triangle index + 1, so that the cleared value 0 means "empty"; exact for any count
// below 2^31 because the target is a 32-bit integer texture.
layout(location = TRI_ID_LOCATION) out int out_tri_id;
uniform int tri_base;  // index of the draw's first triangle (large meshes draw in batches)
#define PRIMITIVE_ID gl_PrimitiveID  // the triangle's index in this draw (raster33/: a varying)
#endif

void main() {
#ifdef OUT_PERSP
    out_persp = v_persp;
#endif
#ifdef OUT_SCREEN
    out_screen = v_screen;
#endif
#ifdef OUT_TRI_ID
    out_tri_id = tri_base + PRIMITIVE_ID + 1;
#endif
}
