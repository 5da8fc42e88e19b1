/* doabench: the image-source part of room impulse responses, one fused pass per image.
 *
 * Built and loaded by doabench/acoustics/native.py (ctypes; no Python headers needed). It
 * computes the early part of doabench.acoustics.rir.render_images on CPU, in one loop (the torch
 * path approximates the same model with a 1/8-sample grid instead):
 * for every (point, image) pair within reach and every microphone, the distance, the amplitude
 * gain / d and the arrival time d fs / c, then the 32 taps of the Hann-windowed sinc (+-16
 * samples) centred on that time, read from a table of the nearest of DB_OVER = 128 phases per
 * sample (arrival times rounded to 1/128 sample: the same accuracy as the earlier linear
 * interpolation between 8 phases, with half the table reads and no interpolation).
 *
 * Why a compiled loop: the torch path needs about fifteen elementwise passes plus scatters per
 * (point, image, microphone) element; this loop keeps everything in registers and writes 32
 * contiguous samples (vectors of the target's width) per element (numbers in docs/performance.md).
 *
 * Floating point: built with -ffp-contract=off, so every product and sum is one IEEE float32
 * operation whatever the instruction set; samples accumulate in image order. Results are bitwise
 * the same on every x86-64 or ARM machine and compiler.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#define DB_HALF 16  /* SINC_HALF: the window spans +-16 samples */
#define DB_OVER 128 /* KERNEL_PHASES (rir.py): table phases per sample (nearest phase) */
#define DB_TAPS 32  /* samples one image touches: 2 * DB_HALF */
#define DB_BLOCK 64 /* images per block of the vectorised distance work */

/* The tap vectors have the target's native width: 16 floats with AVX-512, 8 with AVX/AVX2, 4
 * with SSE or NEON. A vector wider than the target's registers (16 floats on AVX2) makes GCC
 * build the scalar-times-vector broadcast piecewise through the stack, 16 scalar stores and
 * reloads per image: the kernel then ran 6x slower on AVX2 than with AVX-512
 * (docs/performance.md). Unaligned loads and stores go through memcpy, which compiles to single
 * unaligned vector moves. Every sample gets the same float32 product and sum at any width. */
#if defined(__AVX512F__)
#define DB_LANES 16
#elif defined(__AVX__)
#define DB_LANES 8
#else
#define DB_LANES 4
#endif
typedef float db_vec __attribute__((vector_size(DB_LANES * sizeof(float))));

static inline db_vec db_load(const float *p) {
    db_vec v;
    memcpy(&v, p, sizeof v);
    return v;
}

static inline void db_store(float *p, db_vec v) { memcpy(p, &v, sizeof v); }

int doabench_image_kernel_version(void) { return 5; }

/* src (P, 3), mic (M, 3), sign (I, 3), offset (I, 3), gain (I): float32, contiguous, room
 * coordinates relative to a common origin (the array centre).
 * mic_point_stride: floats between the microphones of consecutive points; 0 when every point
 * shares one array (mic is (M, 3)), 3 M for a moving array (mic is (P, M, 3): point p is heard by
 * the microphones at mic + p * mic_point_stride). Arithmetic per element is the same either way.
 * table (DB_OVER, DB_TAPS): table[ph][n] = windowed_sinc(n - (DB_HALF - 1) - ph / DB_OVER).
 * out: row (p, m) starts at out + (p * M + m) * stride (stride >= n_out); its first n_out samples
 * are written (zeroed first), the rest is left alone.
 * reach2: squared distance beyond which an image cannot reach sample n_out of any microphone.
 * scale: fs / c * DB_OVER (fine-grid units per metre).
 * work: scratch of 4 * (I + DB_BLOCK) floats.
 *
 * Loop order: per point, the images within reach are gathered once (structure of arrays); then
 * per microphone, blocks of images get their distances vectorised across images and their taps
 * added into that microphone's row, which stays in the L1 cache with the 16 kB table (the
 * additions are the cost: with all microphones' rows live, each image's samples came from L2,
 * 3x slower). */
int doabench_render_images(int64_t P, int64_t M, int64_t I, const float *restrict src,
                           const float *restrict mic, const float *restrict sign,
                           const float *restrict offset, const float *restrict gain, float reach2,
                           float scale, const float *restrict table, float *restrict out,
                           int64_t n_out, int64_t stride, float *restrict work, int64_t mic_point_stride) {
    float *restrict ix = work, *restrict iy = work + (I + DB_BLOCK), *restrict iz = work + 2 * (I + DB_BLOCK);
    float *restrict ig = work + 3 * (I + DB_BLOCK);
    float w[DB_BLOCK];
    int32_t q[DB_BLOCK];
    for (int64_t r = 0; r < P * M; r++) memset(out + r * stride, 0, (size_t)n_out * sizeof(float));
    for (int64_t p = 0; p < P; p++) {
        const float sx = src[3 * p], sy = src[3 * p + 1], sz = src[3 * p + 2];
        int64_t K = 0; /* images of this point within reach */
        for (int64_t i = 0; i < I; i++) {
            /* branchless compaction: every image is written at K, which only moves on for the
             * images within reach (about a quarter of the images are out of reach, in no
             * predictable order; this loop is about 10 % of the kernel in long-T60 rooms, and
             * the branch-free form measured the same or a little faster: docs/performance.md) */
            const float *sg = sign + 3 * i, *of = offset + 3 * i;
            const float x = of[0] + sg[0] * sx, y = of[1] + sg[1] * sy, z = of[2] + sg[2] * sz;
            ix[K] = x;
            iy[K] = y;
            iz[K] = z;
            ig[K] = gain[i];
            K += x * x + y * y + z * z <= reach2;
        }
        const float *pmic = mic + p * mic_point_stride;
        for (int64_t m = 0; m < M; m++) {
            const float mx = pmic[3 * m], my = pmic[3 * m + 1], mz = pmic[3 * m + 2];
            float *row = out + (p * M + m) * stride;
            for (int64_t k0 = 0; k0 < K; k0 += DB_BLOCK) {
                const int64_t nk = K - k0 < DB_BLOCK ? K - k0 : DB_BLOCK;
                /* distances, amplitudes and arrival times on the 1/DB_OVER grid (vectorised) */
                for (int64_t k = 0; k < nk; k++) {
                    const float dx = ix[k0 + k] - mx, dy = iy[k0 + k] - my, dz = iz[k0 + k] - mz;
                    float d = sqrtf(dx * dx + dy * dy + dz * dz);
                    d = d < 1e-6f ? 1e-6f : d;
                    w[k] = ig[k0 + k] / d;
                    q[k] = (int32_t)(d * scale + 0.5f); /* nearest phase (>= 0) */
                }
                /* 32 taps per image from the nearest phase's table row */
                for (int64_t k = 0; k < nk; k++) {
                    const int64_t base = (int64_t)(q[k] / DB_OVER) - (DB_HALF - 1); /* first sample */
                    const float *t = table + (q[k] % DB_OVER) * DB_TAPS;
                    const float a = w[k];
                    if (base >= 0 && base + DB_TAPS <= n_out) {
                        float *r = row + base;
                        for (int j = 0; j < DB_TAPS; j += DB_LANES)
                            db_store(r + j, db_load(r + j) + a * db_load(t + j));
                    } else {
                        for (int n = 0; n < DB_TAPS; n++) {
                            const int64_t s = base + n;
                            if (s >= 0 && s < n_out) row[s] += a * t[n];
                        }
                    }
                }
            }
        }
    }
    return 0;
}
