/*
 * The C API's reliability cases and a sweep of every function with hostile arguments:
 *   reliability OLD.gman NEW.gman
 * OLD is a blob of format v1-v3 (its CRC skips the header) with commit delay 0, NEW one of
 * format v4; both with the same sizes. Built by tests/tests/capi_reliability.rs with
 * -fsanitize=address,undefined when the compiler supports it. Prints one line per failed
 * check, the sweep's counts, then OK when everything held (exit 0), else exits 1.
 *
 * What must hold:
 *  - a refused gman_init on the arena of a live navigator leaves that navigator running
 *    bit for bit like one that never saw the call;
 *  - a refused gman_step (GMAN_ERR_NUMERICAL from an observation entry of 3e38) changes
 *    nothing: the next 30 steps are those of a navigator that never saw it;
 *  - an output overlapping an input, or a buffer inside the arena, is GMAN_ERR_OVERLAP;
 *  - a misaligned gman_options pointer is GMAN_ERR_ALIGNMENT, whose text is not about floats;
 *  - gman_options.require_header_crc = 1 refuses OLD (GMAN_ERR_BLOB_VERSION), accepts NEW;
 *  - the sweep: every function given NULL, empty, huge, misaligned, overlapping, NaN and
 *    out-of-order arguments returns the expected status, and a navigator that went
 *    through all of it still steps bit for bit like an untouched one.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gman.h"

static int checks = 0, failures = 0;

#define CHECK(cond, ...)                                  \
    do {                                                  \
        checks++;                                         \
        if (!(cond)) {                                    \
            failures++;                                   \
            printf("FAIL line %d: ", __LINE__);           \
            printf(__VA_ARGS__);                          \
            printf("\n");                                 \
        }                                                 \
    } while (0)

#define STATUS(call, want)                                                                  \
    do {                                                                                    \
        gman_status s_ = (call);                                                            \
        CHECK(s_ == (want), "%s gave %d (%s), want %d", #call, (int)s_, gman_status_str(s_), \
              (int)(want));                                                                 \
    } while (0)

/* The sweep: hostile calls, each with the status it must give. */
static int sweep_calls = 0, sweep_wrong = 0;
static unsigned sweep_funcs = 0; /* bit i: function i was called */

#define SWEEP(fn_bit, call, want)                                                          \
    do {                                                                                   \
        gman_status s_ = (call);                                                           \
        sweep_calls++;                                                                     \
        sweep_funcs |= 1u << (fn_bit);                                                     \
        if (s_ != (want)) {                                                                \
            sweep_wrong++;                                                                 \
            printf("FAIL sweep line %d: %s gave %d (%s), want %d\n", __LINE__, #call,      \
                   (int)s_, gman_status_str(s_), (int)(want));                             \
        }                                                                                  \
    } while (0)

enum {
    F_API_VERSION, F_STATUS_STR, F_CRC32, F_INSPECT, F_ARENA_SIZE, F_INIT, F_RESET, F_STEP,
    F_ADAPT_NOW, F_ADAPT_SLICE, F_SETTLE, F_GET_SCHEDULE, F_BUFFERED, F_GET_COUNTERS,
    F_LAST_ADAPTATION, F_NAV_INFO, F_GENERATED_FEATURE, F_GENERATOR_OUTPUT, F_LAST_ERROR,
    F_BLOB_SETTING, F_COUNT
};

typedef struct blob_t {
    uint8_t *bytes;
    size_t len;
} blob_t;

static blob_t slurp(const char *path) {
    blob_t b = {0};
    FILE *fp = fopen(path, "rb");
    if (!fp) return b;
    fseek(fp, 0, SEEK_END);
    long n = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    b.bytes = malloc((size_t)n);
    if (fread(b.bytes, 1, (size_t)n, fp) != (size_t)n) {
        free(b.bytes);
        b.bytes = NULL;
    } else {
        b.len = (size_t)n;
    }
    fclose(fp);
    return b;
}

static gman_info info; /* of both blobs (the same sizes) */

typedef struct nav_t {
    uint8_t *mem;
    size_t len;
    gman_nav *h;
} nav_t;

/* A navigator over `b` in a fresh, deliberately misaligned arena. */
static nav_t make_nav(const blob_t *b, const gman_options *opts) {
    nav_t n = {0};
    n.len = (size_t)info.arena_bytes;
    n.mem = calloc(n.len + 3, 1);
    gman_status s = gman_init(b->bytes, b->len, n.mem + 3, n.len, opts, &n.h);
    CHECK(s == GMAN_OK, "gman_init gave %s", gman_status_str(s));
    return n;
}

/* Deterministic inputs of step t. */
static float obs[4096], map[65536], attr[1024], ps[1024], z[1024], x[4096];

static void inputs(int t) {
    for (uint32_t i = 0; i < info.feat; i++) obs[i] = (float)((t * 7 + (int)i * 3) % 11) / 11.0f;
    for (uint32_t i = 0; i < info.map_len; i++)
        map[i] = (float)((t * 5 + (int)i) % 13) / 13.0f;
    for (uint32_t i = 0; i < info.ps; i++) ps[i] = 0.1f;
}

static gman_status step(gman_nav *h, int t, gman_step_out *o) {
    inputs(t);
    return gman_step(h, obs, info.feat, map, info.map_len, ps, info.ps, o);
}

static gman_status reset(gman_nav *h) {
    for (uint32_t i = 0; i < info.attr; i++) attr[i] = (float)i / (float)info.attr - 0.5f;
    return gman_reset(h, attr, info.attr, 7);
}

/* Steps `a` and `b` through steps t0 .. t0 + n - 1; returns how many steps differed. */
static int lockstep(gman_nav *a, gman_nav *b, int t0, int n) {
    int differ = 0;
    for (int t = t0; t < t0 + n; t++) {
        gman_step_out oa, ob;
        memset(&oa, 0, sizeof oa);
        memset(&ob, 0, sizeof ob);
        gman_status sa = step(a, t, &oa), sb = step(b, t, &ob);
        gman_counters ca, cb;
        gman_get_counters(a, &ca);
        gman_get_counters(b, &cb);
        if (sa != GMAN_OK || sb != GMAN_OK || memcmp(&oa, &ob, sizeof oa) != 0 ||
            memcmp(&ca, &cb, sizeof ca) != 0)
            differ++;
    }
    return differ;
}

/* 1. A refused gman_init on the arena of a live navigator leaves it untouched. */
static void refused_init_leaves_the_live_navigator(const blob_t *old) {
    nav_t live = make_nav(old, NULL), ref = make_nav(old, NULL);
    STATUS(reset(live.h), GMAN_OK);
    STATUS(reset(ref.h), GMAN_OK);
    CHECK(lockstep(live.h, ref.h, 0, 5) == 0, "the navigators differ before the refused init");
    gman_options bg = {.schedule = 2}; /* background needs a commit delay; OLD records 0 */
    gman_nav *other = (gman_nav *)1;
    STATUS(gman_init(old->bytes, old->len, live.mem + 3, live.len, &bg, &other), GMAN_ERR_CONFIG);
    CHECK(other == NULL, "a refused gman_init left *out non-null");
    int d = lockstep(live.h, ref.h, 5, 30);
    CHECK(d == 0, "after a refused gman_init on its arena the live navigator differs in %d of 30 steps", d);
    free(live.mem);
    free(ref.mem);
}

/* 2. A step refused as numerical changes nothing. */
static void refused_step_changes_nothing(const blob_t *b) {
    nav_t a = make_nav(b, NULL), r = make_nav(b, NULL);
    STATUS(reset(a.h), GMAN_OK);
    STATUS(reset(r.h), GMAN_OK);
    CHECK(lockstep(a.h, r.h, 0, 3) == 0, "the navigators differ before the refused step");
    gman_counters before, after;
    gman_get_counters(a.h, &before);
    inputs(3);
    obs[0] = 3e38f;
    gman_step_out o;
    STATUS(gman_step(a.h, obs, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_NUMERICAL);
    gman_get_counters(a.h, &after);
    CHECK(memcmp(&before, &after, sizeof before) == 0, "a refused step changed the counters");
    int d = lockstep(a.h, r.h, 3, 30);
    CHECK(d == 0, "after a step refused as numerical %d of the next 30 steps differ", d);
    free(a.mem);
    free(r.mem);
}

/* 3. Overlapping spans are refused; 6. the alignment text; 5. require_header_crc. */
static void overlap_alignment_and_header_crc(const blob_t *old, const blob_t *new_) {
    nav_t n = make_nav(new_, NULL);
    STATUS(reset(n.h), GMAN_OK);
    float buf[8192];
    memset(buf, 0, sizeof buf);
    /* z and out overlapping (out starts inside z), and the same buffer */
    STATUS(gman_generator_output(n.h, buf, info.noise, buf + 1, info.feat), GMAN_ERR_OVERLAP);
    STATUS(gman_generator_output(n.h, buf, info.noise, buf, info.feat), GMAN_ERR_OVERLAP);
    CHECK(strstr(gman_last_error(n.h), "overlaps") != NULL, "gman_last_error: %s", gman_last_error(n.h));
    STATUS(gman_generator_output(n.h, buf, info.noise, buf + info.noise, info.feat), GMAN_OK);

    uint64_t raw[8] = {0};
    const gman_options *mis = (const gman_options *)((const uint8_t *)raw + 1);
    uint8_t *arena = calloc((size_t)info.arena_bytes, 1);
    gman_nav *h = NULL;
    STATUS(gman_init(new_->bytes, new_->len, arena, (size_t)info.arena_bytes, mis, &h), GMAN_ERR_ALIGNMENT);
    CHECK(strstr(gman_status_str(GMAN_ERR_ALIGNMENT), "float buffer") == NULL,
          "the ALIGNMENT text speaks of a float buffer: %s", gman_status_str(GMAN_ERR_ALIGNMENT));

    gman_options strict = {.require_header_crc = 1};
    STATUS(gman_init(old->bytes, old->len, arena, (size_t)info.arena_bytes, &strict, &h), GMAN_ERR_BLOB_VERSION);
    STATUS(gman_init(new_->bytes, new_->len, arena, (size_t)info.arena_bytes, &strict, &h), GMAN_OK);
    gman_options two = {.require_header_crc = 2};
    STATUS(gman_init(new_->bytes, new_->len, arena, (size_t)info.arena_bytes, &two, &h), GMAN_ERR_CONFIG);
    free(arena);
    free(n.mem);
}

/* The sweep over every function (F_*), on `v` (compared with an untouched twin later). */
static void sweep_handle_functions(nav_t *v, const blob_t *b) {
    float nan = NAN, inf = INFINITY;
    float buf[8192];
    memset(buf, 0, sizeof buf);
    float *mis = (float *)((uint8_t *)buf + 1);
    float *in_arena = (float *)(v->mem + 3 + 8192);
    gman_step_out o;
    gman_step_out *o_mis = (gman_step_out *)((uint8_t *)buf + 2);
    const size_t huge[] = {SIZE_MAX, SIZE_MAX / 4 + 1, (size_t)1 << 40, 1u << 20};
    uint8_t dead_mem[8192 + 16];
    memset(dead_mem, 0, sizeof dead_mem);
    gman_nav *dead = (gman_nav *)(dead_mem + 16 - ((uintptr_t)dead_mem % 16));
    gman_nav *mis_h = (gman_nav *)((uint8_t *)v->h + 1);
    gman_nav *handles[] = {NULL, dead, mis_h};
    gman_status want_h[] = {GMAN_ERR_NULL, GMAN_ERR_BAD_HANDLE, GMAN_ERR_BAD_HANDLE};
    uint32_t u;
    gman_schedule_state ss;
    gman_counters c;
    gman_adapt_report ar;
    gman_info ni;

    /* Every handle function on NULL, a dead handle and a misaligned one. */
    for (int i = 0; i < 3; i++) {
        gman_nav *h = handles[i];
        gman_status w = want_h[i];
        SWEEP(F_RESET, gman_reset(h, attr, info.attr, 1), w);
        SWEEP(F_STEP, gman_step(h, obs, info.feat, map, info.map_len, ps, info.ps, &o), w);
        SWEEP(F_ADAPT_NOW, gman_adapt_now(h, &u), w);
        SWEEP(F_ADAPT_SLICE, gman_adapt_slice(h, &u), w);
        SWEEP(F_SETTLE, gman_settle(h), w);
        SWEEP(F_GET_SCHEDULE, gman_get_schedule(h, &ss), w);
        SWEEP(F_BUFFERED, gman_buffered(h, &u), w);
        SWEEP(F_GET_COUNTERS, gman_get_counters(h, &c), w);
        SWEEP(F_LAST_ADAPTATION, gman_last_adaptation(h, &ar), w);
        SWEEP(F_NAV_INFO, gman_nav_info(h, &ni), w);
        SWEEP(F_GENERATED_FEATURE, gman_generated_feature(h, x, info.feat), w);
        SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(h, z, info.noise, x, info.feat), w);
        sweep_calls++;
        sweep_funcs |= 1u << F_LAST_ERROR;
        if (gman_last_error(h) == NULL || strlen(gman_last_error(h)) == 0) {
            sweep_wrong++;
            printf("FAIL sweep: gman_last_error of a bad handle is empty\n");
        }
    }

    /* Out-parameters: NULL, misaligned, inside the arena. */
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, NULL), GMAN_ERR_NULL);
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, o_mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, (gman_step_out *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_GET_SCHEDULE, gman_get_schedule(v->h, NULL), GMAN_ERR_NULL);
    SWEEP(F_GET_SCHEDULE, gman_get_schedule(v->h, (gman_schedule_state *)mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_GET_SCHEDULE, gman_get_schedule(v->h, (gman_schedule_state *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_BUFFERED, gman_buffered(v->h, NULL), GMAN_ERR_NULL);
    SWEEP(F_BUFFERED, gman_buffered(v->h, (uint32_t *)mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_BUFFERED, gman_buffered(v->h, (uint32_t *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_GET_COUNTERS, gman_get_counters(v->h, NULL), GMAN_ERR_NULL);
    SWEEP(F_GET_COUNTERS, gman_get_counters(v->h, (gman_counters *)mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_GET_COUNTERS, gman_get_counters(v->h, (gman_counters *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_LAST_ADAPTATION, gman_last_adaptation(v->h, NULL), GMAN_ERR_NULL);
    SWEEP(F_LAST_ADAPTATION, gman_last_adaptation(v->h, (gman_adapt_report *)mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_LAST_ADAPTATION, gman_last_adaptation(v->h, (gman_adapt_report *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_NAV_INFO, gman_nav_info(v->h, NULL), GMAN_ERR_NULL);
    SWEEP(F_NAV_INFO, gman_nav_info(v->h, (gman_info *)mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_NAV_INFO, gman_nav_info(v->h, (gman_info *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_ADAPT_NOW, gman_adapt_now(v->h, (uint32_t *)in_arena), GMAN_ERR_OVERLAP);
    SWEEP(F_ADAPT_SLICE, gman_adapt_slice(v->h, (uint32_t *)mis), GMAN_ERR_ALIGNMENT);
    SWEEP(F_ADAPT_SLICE, gman_adapt_slice(v->h, (uint32_t *)in_arena), GMAN_ERR_OVERLAP);

    /* Float spans: NULL with a length, empty, huge, one too long, misaligned, NaN/inf,
     * overlapping an output or the arena. */
    SWEEP(F_RESET, gman_reset(v->h, NULL, info.attr, 1), GMAN_ERR_NULL);
    SWEEP(F_RESET, gman_reset(v->h, attr, 0, 1), GMAN_ERR_SHAPE);
    SWEEP(F_RESET, gman_reset(v->h, mis, info.attr, 1), GMAN_ERR_ALIGNMENT);
    SWEEP(F_RESET, gman_reset(v->h, in_arena, info.attr, 1), GMAN_ERR_OVERLAP);
    SWEEP(F_STEP, gman_step(v->h, NULL, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_NULL);
    SWEEP(F_STEP, gman_step(v->h, obs, 0, map, info.map_len, ps, info.ps, &o), GMAN_ERR_SHAPE);
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, NULL, 0, ps, info.ps, &o), info.map_len ? GMAN_ERR_SHAPE : GMAN_OK);
    SWEEP(F_STEP, gman_step(v->h, mis, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_ALIGNMENT);
    SWEEP(F_STEP, gman_step(v->h, in_arena, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_OVERLAP);
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, (gman_step_out *)obs), GMAN_ERR_OVERLAP);
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, (gman_step_out *)(map + 3)), GMAN_ERR_OVERLAP);
    SWEEP(F_GENERATED_FEATURE, gman_generated_feature(v->h, NULL, info.feat), GMAN_ERR_NULL);
    SWEEP(F_GENERATED_FEATURE, gman_generated_feature(v->h, x, 0), GMAN_ERR_SHAPE);
    SWEEP(F_GENERATED_FEATURE, gman_generated_feature(v->h, mis, info.feat), GMAN_ERR_ALIGNMENT);
    SWEEP(F_GENERATED_FEATURE, gman_generated_feature(v->h, in_arena, info.feat), GMAN_ERR_OVERLAP);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, NULL, info.noise, x, info.feat), GMAN_ERR_NULL);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, z, info.noise, NULL, info.feat), GMAN_ERR_NULL);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, z, 0, x, info.feat), GMAN_ERR_SHAPE);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, mis, info.noise, x, info.feat), GMAN_ERR_ALIGNMENT);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, z, info.noise, in_arena, info.feat), GMAN_ERR_OVERLAP);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, in_arena, info.noise, x, info.feat), GMAN_ERR_OVERLAP);
    for (size_t i = 0; i < sizeof huge / sizeof huge[0]; i++) {
        size_t n = huge[i];
        SWEEP(F_RESET, gman_reset(v->h, attr, n, 1), GMAN_ERR_SHAPE);
        SWEEP(F_STEP, gman_step(v->h, obs, n, map, info.map_len, ps, info.ps, &o), GMAN_ERR_SHAPE);
        SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, n, ps, info.ps, &o), GMAN_ERR_SHAPE);
        SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, n, &o), GMAN_ERR_SHAPE);
        SWEEP(F_GENERATED_FEATURE, gman_generated_feature(v->h, x, n), GMAN_ERR_SHAPE);
        SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, z, n, x, info.feat), GMAN_ERR_SHAPE);
        SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, z, info.noise, x, n), GMAN_ERR_SHAPE);
        if (n > ((size_t)1 << 33)) { /* longer than any blob: refused unread */
            SWEEP(F_INSPECT, gman_inspect(b->bytes, n, &ni), GMAN_ERR_BLOB);
            size_t as = 0;
            SWEEP(F_ARENA_SIZE, gman_arena_size(b->bytes, n, &as), GMAN_ERR_BLOB);
        }
        sweep_calls++;
        sweep_funcs |= 1u << F_CRC32;
        if (n > (SIZE_MAX >> 1) && gman_crc32(0, b->bytes, n) != 0) {
            sweep_wrong++;
            printf("FAIL sweep: gman_crc32 with a length past isize::MAX is not 0\n");
        }
    }
    float bad[] = {nan, inf, -inf};
    for (int i = 0; i < 3; i++) {
        inputs(0);
        obs[1] = bad[i];
        SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_NON_FINITE);
        inputs(0);
        if (info.map_len) {
            map[info.map_len - 1] = bad[i];
            SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_NON_FINITE);
        }
        inputs(0);
        for (uint32_t j = 0; j < info.noise; j++) z[j] = 0.5f;
        z[0] = bad[i];
        SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(v->h, z, info.noise, x, info.feat), GMAN_ERR_NON_FINITE);
        float a2[1024];
        memcpy(a2, attr, sizeof a2);
        a2[0] = bad[i];
        SWEEP(F_RESET, gman_reset(v->h, a2, info.attr, 1), GMAN_ERR_NON_FINITE);
    }
    /* Finite but overflowing: refused as numerical, changing nothing. */
    inputs(0);
    obs[0] = 3e38f;
    SWEEP(F_STEP, gman_step(v->h, obs, info.feat, map, info.map_len, ps, info.ps, &o), GMAN_ERR_NUMERICAL);
    inputs(0);
    SWEEP(F_STATUS_STR, gman_status_str(-1) != NULL && gman_status_str(1 << 30) != NULL ? GMAN_OK : -1, GMAN_OK);
    SWEEP(F_API_VERSION, gman_api_version() == GMAN_API_VERSION ? GMAN_OK : -1, GMAN_OK);
}

/* The blob functions and gman_init: NULL, empty, truncated, overlapping, misaligned. */
static void sweep_blob_functions(const blob_t *b, nav_t *v) {
    gman_info ni;
    size_t as;
    gman_nav *h;
    uint8_t *arena = calloc((size_t)info.arena_bytes + 1, 1);
    size_t alen = (size_t)info.arena_bytes;
    SWEEP(F_INSPECT, gman_inspect(NULL, b->len, &ni), GMAN_ERR_NULL);
    SWEEP(F_INSPECT, gman_inspect(b->bytes, b->len, NULL), GMAN_ERR_NULL);
    SWEEP(F_INSPECT, gman_inspect(b->bytes, 0, &ni), GMAN_ERR_BLOB);
    SWEEP(F_INSPECT, gman_inspect(b->bytes, 10, &ni), GMAN_ERR_BLOB);
    SWEEP(F_INSPECT, gman_inspect(b->bytes, b->len - 1, &ni), GMAN_ERR_BLOB);
    uint64_t raw[64];
    SWEEP(F_INSPECT, gman_inspect(b->bytes, b->len, (gman_info *)((uint8_t *)raw + 1)), GMAN_ERR_ALIGNMENT);
    SWEEP(F_ARENA_SIZE, gman_arena_size(b->bytes, b->len, (size_t *)((uint8_t *)raw + 1)), GMAN_ERR_ALIGNMENT);
    SWEEP(F_INSPECT, gman_inspect(b->bytes, b->len, (gman_info *)(b->bytes + 64)), GMAN_ERR_OVERLAP);
    SWEEP(F_ARENA_SIZE, gman_arena_size(NULL, b->len, &as), GMAN_ERR_NULL);
    SWEEP(F_ARENA_SIZE, gman_arena_size(b->bytes, b->len, NULL), GMAN_ERR_NULL);
    SWEEP(F_ARENA_SIZE, gman_arena_size(b->bytes, b->len, (size_t *)(b->bytes + 64)), GMAN_ERR_OVERLAP);
    gman_setting gs;
    SWEEP(F_BLOB_SETTING, gman_blob_setting(NULL, b->len, 0, &gs), GMAN_ERR_NULL);
    SWEEP(F_BLOB_SETTING, gman_blob_setting(b->bytes, b->len, 0, NULL), GMAN_ERR_NULL);
    SWEEP(F_BLOB_SETTING, gman_blob_setting(b->bytes, b->len - 1, 0, &gs), GMAN_ERR_BLOB);
    SWEEP(F_BLOB_SETTING, gman_blob_setting(b->bytes, b->len, 0, (gman_setting *)((uint8_t *)raw + 1)), GMAN_ERR_ALIGNMENT);
    SWEEP(F_BLOB_SETTING, gman_blob_setting(b->bytes, b->len, 0, (gman_setting *)(b->bytes + 64)), GMAN_ERR_OVERLAP);
    SWEEP(F_BLOB_SETTING, gman_blob_setting(b->bytes, b->len, 1u << 31, &gs), GMAN_OK);
    CHECK(gs.key[0] == 0, "past the last setting the key is empty");
    SWEEP(F_INIT, gman_init(NULL, b->len, arena, alen, NULL, &h), GMAN_ERR_NULL);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, NULL, alen, NULL, &h), GMAN_ERR_NULL);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, NULL, NULL), GMAN_ERR_NULL);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen - 1, NULL, &h), GMAN_ERR_ARENA_TOO_SMALL);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, 0, NULL, &h), GMAN_ERR_ARENA_TOO_SMALL);
    SWEEP(F_INIT, gman_init(b->bytes, 7, arena, alen, NULL, &h), GMAN_ERR_BLOB);
    SWEEP(F_INIT, gman_init(b->bytes, SIZE_MAX, arena, alen, NULL, &h), GMAN_ERR_BLOB);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, NULL, (gman_nav **)(arena + 8)), GMAN_ERR_OVERLAP);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, (const gman_options *)(arena + 16), &h), GMAN_ERR_OVERLAP);
    /* The live navigator's own arena as the blob of another init, and its handle as out. */
    SWEEP(F_INIT, gman_init(v->mem + 3, b->len < v->len ? b->len : v->len, arena, alen, NULL, &h), GMAN_ERR_BLOB);
    SWEEP(F_INIT, gman_init(b->bytes, b->len, v->mem + 3, v->len, NULL, (gman_nav **)(v->mem + 64)), GMAN_ERR_OVERLAP);
    gman_options o = {.selection = 9};
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, &o, &h), GMAN_ERR_CONFIG);
    o.selection = 0;
    o.schedule = 3;
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, &o, &h), GMAN_ERR_CONFIG);
    o.schedule = 0;
    o.settings.commit_delay = 64;
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, &o, &h), GMAN_ERR_CONFIG);
    o.settings.commit_delay = 0;
    o.settings.adapt = 1; /* the blob's settings are the model's: only the delay is the device's */
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena, alen, &o, &h), GMAN_ERR_CONFIG);
    /* A corrupt copy: one bit flipped in the payload. */
    uint8_t *copy = malloc(b->len);
    memcpy(copy, b->bytes, b->len);
    copy[b->len / 2] ^= 4;
    SWEEP(F_INIT, gman_init(copy, b->len, arena, alen, NULL, &h), GMAN_ERR_BLOB_CRC);
    SWEEP(F_INSPECT, gman_inspect(copy, b->len, &ni), GMAN_ERR_BLOB_CRC);
    free(copy);
    /* Out of order on a fresh navigator: before gman_reset. */
    SWEEP(F_INIT, gman_init(b->bytes, b->len, arena + 1, alen, NULL, &h), GMAN_OK);
    gman_step_out so;
    uint32_t u;
    SWEEP(F_STEP, gman_step(h, obs, info.feat, map, info.map_len, ps, info.ps, &so), GMAN_ERR_CONFIG);
    SWEEP(F_ADAPT_NOW, gman_adapt_now(h, &u), GMAN_ERR_CONFIG);
    SWEEP(F_GENERATOR_OUTPUT, gman_generator_output(h, z, info.noise, x, info.feat), GMAN_ERR_CONFIG);
    SWEEP(F_ADAPT_SLICE, gman_adapt_slice(h, &u), GMAN_OK); /* nothing pending: a no-op */
    CHECK(u == 0, "gman_adapt_slice with nothing pending says more = %u", u);
    SWEEP(F_SETTLE, gman_settle(h), GMAN_OK);
    /* The arena overwritten by the caller: the handle is dead. */
    memset(arena, 0, alen + 1);
    SWEEP(F_STEP, gman_step(h, obs, info.feat, map, info.map_len, ps, info.ps, &so), GMAN_ERR_BAD_HANDLE);
    free(arena);
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s OLD.gman NEW.gman\n", argv[0]);
        return 2;
    }
    blob_t old = slurp(argv[1]), new_ = slurp(argv[2]);
    if (!old.bytes || !new_.bytes) {
        fprintf(stderr, "cannot read the blobs\n");
        return 2;
    }
    gman_info oi;
    STATUS(gman_inspect(old.bytes, old.len, &oi), GMAN_OK);
    STATUS(gman_inspect(new_.bytes, new_.len, &info), GMAN_OK);
    CHECK(oi.format_version < 4 && info.format_version >= 4 && oi.settings.commit_delay == 0,
          "want an old blob with delay 0 and a v4 one (got v%u delay %u, v%u)",
          oi.format_version, oi.settings.commit_delay, info.format_version);
    CHECK(oi.arena_bytes == info.arena_bytes && oi.feat == info.feat, "the blobs' sizes differ");
    if (failures) return 1;

    refused_init_leaves_the_live_navigator(&old);
    refused_step_changes_nothing(&new_);
    overlap_alignment_and_header_crc(&old, &new_);

    /* The sweep on `v`; `r` gets only the good calls. Then both must step alike. */
    nav_t v = make_nav(&new_, NULL), r = make_nav(&new_, NULL);
    STATUS(reset(v.h), GMAN_OK);
    STATUS(reset(r.h), GMAN_OK);
    CHECK(lockstep(v.h, r.h, 0, 7) == 0, "differ before the sweep");
    sweep_handle_functions(&v, &new_);
    sweep_blob_functions(&new_, &v);
    inputs(0);
    int d = lockstep(v.h, r.h, 7, 40);
    CHECK(d == 0, "after the sweep the navigator differs from an untouched one in %d of 40 steps", d);
    int funcs = 0;
    for (int i = 0; i < F_COUNT; i++) funcs += (sweep_funcs >> i) & 1;
    printf("sweep: %d calls over %d of %d functions, %d with an unexpected result\n", sweep_calls,
           funcs, (int)F_COUNT, sweep_wrong);
    printf("checks: %d, failed %d\n", checks, failures);
    free(v.mem);
    free(r.mem);
    free(old.bytes);
    free(new_.bytes);
    if (failures || sweep_wrong || funcs != F_COUNT) return 1;
    printf("OK\n");
    return 0;
}
