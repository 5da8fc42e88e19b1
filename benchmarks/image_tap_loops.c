/* The per-image tap loops of doabench/acoustics/image_sources.c in isolation: ns per
 * (image, microphone) for 3,000 images x 12 microphones into one 4,000-sample row.
 *   kernel 3: 34 taps interpolated between two of 8 phases (three 16-float vectors, 48-lane rows)
 *   nearest over 48 lanes: one phase of 128, three vectors
 *   kernel 4: one phase of 128, 32 taps (two vectors)
 * Build and run (numbers in docs/performance.md):
 *   gcc -O3 -march=native -ffp-contract=off -fno-math-errno benchmarks/image_tap_loops.c -o /tmp/taps -lm && /tmp/taps
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
typedef float v16 __attribute__((vector_size(64)));
static inline v16 ld(const float *p) { v16 v; memcpy(&v, p, 64); return v; }
static inline void st(float *p, v16 v) { memcpy(p, &v, 64); }
#define NOUT 4000
#define K 3000
#define M 12
#define REPS 200
static float row[NOUT + 256], tab8[9 * 48], tab128_48[128 * 48], tab128[128 * 32];
static int q8[K], base[K], ph[K];
static float w0[K], w1[K], w[K];
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(void) {
    srand(1);
    for (int i = 0; i < 9 * 48; i++) tab8[i] = rand() / (float)RAND_MAX;
    for (int i = 0; i < 128 * 48; i++) tab128_48[i] = rand() / (float)RAND_MAX;
    for (int i = 0; i < 128 * 32; i++) tab128[i] = rand() / (float)RAND_MAX;
    for (int k = 0; k < K; k++) {
        float t = 200 + (NOUT - 300) * (rand() / (float)RAND_MAX), f;
        q8[k] = (int)(t * 8); f = t * 8 - q8[k]; w1[k] = f; w0[k] = 1 - f; w[k] = 1;
        int p = (int)(t * 128 + 0.5f); base[k] = p / 128 - 15; ph[k] = p % 128;
    }
    double t0 = now();
    for (int r = 0; r < REPS; r++) for (int m = 0; m < M; m++) for (int k = 0; k < K; k++) {
        const float *a0 = tab8 + (q8[k] % 8) * 48, *a1 = a0 + 48; float *o = row + q8[k] / 8 - 16;
        for (int n = 0; n < 48; n += 16) st(o + n, ld(o + n) + (w0[k] * ld(a0 + n) + w1[k] * ld(a1 + n)));
    }
    double t1 = now();
    for (int r = 0; r < REPS; r++) for (int m = 0; m < M; m++) for (int k = 0; k < K; k++) {
        const float *a = tab128_48 + ph[k] * 48; float *o = row + base[k];
        for (int n = 0; n < 48; n += 16) st(o + n, ld(o + n) + w[k] * ld(a + n));
    }
    double t2 = now();
    for (int r = 0; r < REPS; r++) for (int m = 0; m < M; m++) for (int k = 0; k < K; k++) {
        const float *a = tab128 + ph[k] * 32; float *o = row + base[k];
        st(o, ld(o) + w[k] * ld(a)); st(o + 16, ld(o + 16) + w[k] * ld(a + 16));
    }
    double t3 = now(), n = (double)REPS * M * K;
    printf("kernel 3 (34 taps, linear between 8 phases): %.2f ns\n", (t1 - t0) / n * 1e9);
    printf("nearest of 128 phases over 48 lanes:        %.2f ns\n", (t2 - t1) / n * 1e9);
    printf("kernel 4 (32 taps, nearest of 128 phases):  %.2f ns   (checksum %g)\n", (t3 - t2) / n * 1e9, row[100]);
    return 0;
}
