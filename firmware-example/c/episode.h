/*
 * The recorded episode (data/episode.gmep, format in ../src/episode.rs) run through the C API
 * of gman-core: the same lines the Rust firmware prints, on any target. Needs no libc.
 */
#ifndef GMAN_EPISODE_H
#define GMAN_EPISODE_H

#include <stddef.h>
#include <stdint.h>

/* Where the episode file comes from and where the lines go. */
typedef struct ep_io {
    void *ctx;
    /* Length of the episode file in bytes, or -1. */
    long (*len)(void *ctx);
    /* Reads n bytes at offset into buf; 0 on success. */
    int (*read_at)(void *ctx, size_t offset, uint8_t *buf, size_t n);
    /* One output line (NUL-terminated, no newline). */
    void (*line)(void *ctx, const char *text);
} ep_io;

/*
 * Runs the episode with a navigator over blob (blob_len bytes) in arena (arena_len bytes)
 * on the given schedule (gman_options.schedule: 0 automatic, the Rust firmware's; 2
 * background, one gman_adapt_slice before each step and the rest when a step is not ready:
 * the same lines but for the "schedule:" one). Returns NULL on success, else a static
 * description of the failure.
 */
const char *ep_run(const uint8_t *blob, size_t blob_len, void *arena, size_t arena_len,
                   uint32_t schedule, ep_io *io);

#endif
