#version 330 core
// Exact readback of multisample targets: every sample copied with texelFetch into a
// single-sample target S times as wide, sample s of pixel (x, y) at (S x + s, y), so that
// the read-back rows are (H, W, S, C) in C order. Never the averaging blit: ids and
// barycentrics of different fragments must not be mixed (GL 4.5 core section 18.3.1
// lets a multisample-to-single-sample glBlitFramebuffer combine samples in any way).
//
// Host defines: SAMPLES; per slot k in 0 .. 7 that is used, SLOT<k>_SAMPLER (sampler2DMS,
// isampler2DMS or usampler2DMS, matching the multisample target read at texture unit
// u_in<k>) and SLOT<k>_VEC (vec4, ivec4, uvec4: the single-sample target at location k).

#define SLOT_MAIN(k) out##k = SLOT##k##_VEC(texelFetch(u_in##k, src, s))
#ifdef SLOT0_SAMPLER
uniform SLOT0_SAMPLER u_in0; layout(location = 0) out SLOT0_VEC out0;
#endif
#ifdef SLOT1_SAMPLER
uniform SLOT1_SAMPLER u_in1; layout(location = 1) out SLOT1_VEC out1;
#endif
#ifdef SLOT2_SAMPLER
uniform SLOT2_SAMPLER u_in2; layout(location = 2) out SLOT2_VEC out2;
#endif
#ifdef SLOT3_SAMPLER
uniform SLOT3_SAMPLER u_in3; layout(location = 3) out SLOT3_VEC out3;
#endif
#ifdef SLOT4_SAMPLER
uniform SLOT4_SAMPLER u_in4; layout(location = 4) out SLOT4_VEC out4;
#endif
#ifdef SLOT5_SAMPLER
uniform SLOT5_SAMPLER u_in5; layout(location = 5) out SLOT5_VEC out5;
#endif
#ifdef SLOT6_SAMPLER
uniform SLOT6_SAMPLER u_in6; layout(location = 6) out SLOT6_VEC out6;
#endif
#ifdef SLOT7_SAMPLER
uniform SLOT7_SAMPLER u_in7; layout(location = 7) out SLOT7_VEC out7;
#endif

void main() {
    ivec2 dst = ivec2(gl_FragCoord.xy);
    ivec2 src = ivec2(dst.x / SAMPLES, dst.y);
    int s = dst.x - SAMPLES * src.x;
#ifdef SLOT0_SAMPLER
    SLOT_MAIN(0);
#endif
#ifdef SLOT1_SAMPLER
    SLOT_MAIN(1);
#endif
#ifdef SLOT2_SAMPLER
    SLOT_MAIN(2);
#endif
#ifdef SLOT3_SAMPLER
    SLOT_MAIN(3);
#endif
#ifdef SLOT4_SAMPLER
    SLOT_MAIN(4);
#endif
#ifdef SLOT5_SAMPLER
    SLOT_MAIN(5);
#endif
#ifdef SLOT6_SAMPLER
    SLOT_MAIN(6);
#endif
#ifdef SLOT7_SAMPLER
    SLOT_MAIN(7);
#endif
}
