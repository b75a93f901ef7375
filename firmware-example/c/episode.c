/*
 * The recorded episode through the C API; mirrors ../src/episode.rs line for line, so that
 * its output is the Rust firmware's bit for bit. Compile with -ffp-contract=off
 * -fno-math-errno (no fused multiply-add: the same float operations as the Rust side).
 */
#include "episode.h"

#include "gman.h"

#define FEAT 512
#define ATTR 45
#define CELLS 9
#define NOISE_MAX 64
#define LABEL_MAX 160
#define HEADER_LEN 28
#define STEP_BYTES ((1 + CELLS) * FEAT)
/* The commit delay the episode runs at when the blob records none (../src/episode.rs:
 * COMMIT_DELAY; a blob's own non-zero delay wins). */
#define COMMIT_DELAY 20

/* ---- a tiny line formatter (no libc) ---- */
typedef struct line {
    char buf[256];
    size_t n;
} line;

static void put_c(line *l, char c) {
    if (l->n + 1 < sizeof l->buf) l->buf[l->n++] = c;
    l->buf[l->n] = 0;
}
static void put_s(line *l, const char *s) {
    while (*s) put_c(l, *s++);
}
static void put_sn(line *l, const char *s, size_t n) {
    for (size_t i = 0; i < n; i++) put_c(l, s[i]);
}
static void put_u64(line *l, uint64_t v, int width) {
    char t[24];
    int k = 0;
    do {
        t[k++] = (char)('0' + (int)(v % 10));
        v /= 10;
    } while (v);
    while (k < width) t[k++] = '0';
    while (k) put_c(l, t[--k]);
}
static void put_hex8(line *l, uint32_t v) {
    for (int i = 7; i >= 0; i--) put_c(l, "0123456789abcdef"[(v >> (4 * i)) & 15u]);
}
static uint32_t bits(float f) {
    union { float f; uint32_t u; } x;
    x.f = f;
    return x.u;
}
static void put_bits(line *l, float f) { put_hex8(l, bits(f)); }
/* Rust's Fixed6: six decimals, rounded down, from integers. */
static void put_fixed6(line *l, float v) {
    uint64_t m = (uint64_t)(v * 1.0e6f);
    put_u64(l, m / 1000000u, 0);
    put_c(l, '.');
    put_u64(l, m % 1000000u, 6);
}
static void put_bool(line *l, uint32_t b) { put_s(l, b ? "true" : "false"); }
static void emit(ep_io *io, line *l) {
    io->line(io->ctx, l->buf);
    l->n = 0;
    l->buf[0] = 0;
}

static const char *const ACTION_NAMES[GMAN_NUM_ACTIONS] = {
    "MoveAhead", "RotateLeft", "RotateRight", "LookUp", "LookDown", "Done"};

static uint16_t u16_at(const uint8_t *b, size_t at) {
    return (uint16_t)(b[at] | (b[at + 1] << 8));
}

/* ||a - b|| (||a|| without b), summed in order, as the Rust side does. */
static float norm_from(const float *a, const float *b, size_t n) {
    float s = 0.0f;
    for (size_t i = 0; i < n; i++) {
        float d = a[i] - (b ? b[i] : 0.0f);
        s += d * d;
    }
    return __builtin_sqrtf(s);
}

/* The episode's buffers (static: a device's stack is small). */
static float obs[FEAT];
static float map[CELLS * FEAT];
static float g0[FEAT];
static float gx[FEAT];
static float zero_z[NOISE_MAX];
static uint8_t chunk[FEAT];

#define TRY(call)                                                                  \
    do {                                                                           \
        gman_status s_ = (call);                                                   \
        if (s_ != GMAN_OK) return nav ? gman_last_error(nav) : gman_status_str(s_); \
    } while (0)

const char *ep_run(const uint8_t *blob, size_t blob_len, void *arena, size_t arena_len,
                   uint32_t schedule, ep_io *io) {
    gman_nav *nav = 0;
    line l = {{0}, 0};
    uint8_t h[HEADER_LEN];

    /* The episode header, lengths and CRC (../src/episode.rs: Episode::parse). */
    long len = io->len(io->ctx);
    if (len < HEADER_LEN) return "episode file: truncated header";
    if (io->read_at(io->ctx, 0, h, HEADER_LEN)) return "episode file: read failed";
    if (h[0] != 'G' || h[1] != 'M' || h[2] != 'E' || h[3] != 'P') return "episode file: bad magic";
    if (u16_at(h, 4) != 2) return "episode file: unsupported version";
    size_t n = u16_at(h, 6);
    if (u16_at(h, 8) != FEAT || u16_at(h, 10) != ATTR)
        return "episode file: feature or attribute width differs from the model's";
    if (u16_at(h, 20) != CELLS) return "episode file: map cells differ from the model's (3 x 3 = 9)";
    uint64_t seed = 0;
    for (int i = 7; i >= 0; i--) seed = (seed << 8) | h[12 + i];
    size_t label_len = u16_at(h, 22);
    if (label_len > LABEL_MAX) return "episode file: label longer than LABEL_MAX";
    uint32_t crc = (uint32_t)h[24] | ((uint32_t)h[25] << 8) | ((uint32_t)h[26] << 16) |
                   ((uint32_t)h[27] << 24);
    size_t body = label_len + 4 * ATTR + n + n * (size_t)STEP_BYTES;
    if ((size_t)len - HEADER_LEN != body) return "episode file: length does not match the header";
    uint32_t c = 0;
    for (size_t at = HEADER_LEN; at < (size_t)len;) {
        size_t m = (size_t)len - at < FEAT ? (size_t)len - at : FEAT;
        if (io->read_at(io->ctx, at, chunk, m)) return "episode file: read failed";
        c = gman_crc32(c, chunk, m);
        at += m;
    }
    if (c != crc) return "episode file: CRC mismatch";
    char label[LABEL_MAX];
    if (io->read_at(io->ctx, HEADER_LEN, (uint8_t *)label, label_len)) return "episode file: read failed";
    size_t attr_at = HEADER_LEN + label_len;
    uint8_t raw[4 * ATTR];
    float attr[ATTR];
    if (io->read_at(io->ctx, attr_at, raw, sizeof raw)) return "episode file: read failed";
    for (int i = 0; i < ATTR; i++) {
        union { uint32_t u; float f; } x;
        x.u = (uint32_t)raw[4 * i] | ((uint32_t)raw[4 * i + 1] << 8) |
              ((uint32_t)raw[4 * i + 2] << 16) | ((uint32_t)raw[4 * i + 3] << 24);
        attr[i] = x.f;
    }
    size_t script_at = attr_at + 4 * ATTR;
    size_t obs_at = script_at + n;

    /* The navigator: blob in place, all state in the caller's arena. */
    gman_info info;
    TRY(gman_inspect(blob, blob_len, &info));
    if (info.feat != FEAT || info.attr != ATTR || info.map_rows * info.map_cols != CELLS ||
        info.noise > NOISE_MAX)
        return "the blob's sizes are not the episode's (Mcu with a 3 x 3 map)";
    /* Greedy, any blob format, the blob's settings with d = COMMIT_DELAY if it records none. */
    gman_options opts = {.schedule = schedule};
    opts.settings.commit_delay = info.settings.commit_delay ? 0 : COMMIT_DELAY;
    TRY(gman_init(blob, blob_len, arena, arena_len, &opts, &nav));
    gman_schedule_state sched;
    TRY(gman_get_schedule(nav, &sched));
    gman_info running; /* the settings the navigator runs (the delay it runs at) */
    TRY(gman_nav_info(nav, &running));
    const gman_settings *set = &info.settings;

    put_s(&l, "episode: ");
    put_sn(&l, label, label_len);
    put_s(&l, " (");
    put_u64(&l, n, 0);
    put_s(&l, " steps, seed ");
    put_u64(&l, seed, 0);
    put_s(&l, ")");
    emit(io, &l);

    put_s(&l, "navigator: Mcu, ");
    put_u64(&l, info.map_rows, 0);
    put_c(&l, 'x');
    put_u64(&l, info.map_cols, 0);
    put_s(&l, " map, ");
    put_s(&l, set->adapt_mode ? "Full" : "Efficient");
    put_s(&l, ", K=");
    put_u64(&l, info.buffer_capacity, 0);
    put_s(&l, ", max_inner_updates=");
    put_u64(&l, set->max_inner_updates, 0);
    emit(io, &l);

    put_s(&l, "config from blob v");
    put_u64(&l, info.format_version, 0);
    put_s(&l, ": adapt=");
    put_u64(&l, set->adapt, 0);
    put_s(&l, set->emd ? " emd=CosSim" : " emd=Discriminator");
    put_s(&l, set->noise_mode ? " noise=Zero" : " noise=Gaussian");
    put_s(&l, " alpha_disc=");
    put_bits(&l, set->alpha_disc);
    put_s(&l, " alpha_adapt=");
    put_bits(&l, set->alpha_adapt);
    emit(io, &l);

    static const char *const SCHEDULE_NAMES[3] = {"Auto", "Manual", "Background"};
    put_s(&l, "schedule: ");
    put_s(&l, sched.schedule < 3 ? SCHEDULE_NAMES[sched.schedule] : "?");
    put_s(&l, ", commit_delay=");
    put_u64(&l, running.settings.commit_delay, 0);
    put_s(&l, " (blob: ");
    put_u64(&l, set->commit_delay, 0);
    put_c(&l, ')');
    emit(io, &l);

    TRY(gman_reset(nav, attr, ATTR, seed));
    TRY(gman_generator_output(nav, zero_z, info.noise, g0, FEAT));
    put_s(&l, "G(SE(y), 0) before adaptation: |x|=");
    put_fixed6(&l, norm_from(g0, 0, FEAT));
    emit(io, &l);

    /* The step whose Ψ filled, while its update is pending (-1: none). */
    long filled_at = -1;
    for (size_t t = 0; t < n; t++) {
        /* Step t's observations, dequantised as the Rust side does (b / 255). */
        size_t at = obs_at + t * (size_t)STEP_BYTES;
        for (size_t i = 0; i <= CELLS; i++) {
            float *out = i == 0 ? obs : map + (i - 1) * FEAT;
            if (io->read_at(io->ctx, at + i * FEAT, chunk, FEAT)) return "episode file: read failed";
            for (size_t j = 0; j < FEAT; j++) out[j] = (float)chunk[j] / 255.0f;
        }
        gman_step_out o;
        gman_counters cn;
        if (schedule == 2) TRY(gman_adapt_slice(nav, NULL)); /* the background's share */
        gman_status s = gman_step(nav, obs, FEAT, map, CELLS * FEAT, NULL, 0, &o);
        if (s == GMAN_ERR_UPDATE_NOT_READY) {
            /* The background fell behind: the step changed nothing; finish, step again. */
            uint32_t more = 1;
            while (more) TRY(gman_adapt_slice(nav, &more));
            s = gman_step(nav, obs, FEAT, map, CELLS * FEAT, NULL, 0, &o);
        }
        TRY(s);
        TRY(gman_get_counters(nav, &cn));
        TRY(gman_get_schedule(nav, &sched));
        if (o.adapted) {
            uint64_t after = filled_at < 0 ? 1 : (uint64_t)t - (uint64_t)filled_at;
            filled_at = -1;
            put_s(&l, "  update committed ");
            put_u64(&l, after, 0);
            put_s(&l, " steps after \xce\xa8 filled");
            emit(io, &l);
        } else if (sched.pending && filled_at < 0) {
            filled_at = (long)t;
        }
        uint8_t scripted = 0xff;
        if (io->read_at(io->ctx, script_at + t, &scripted, 1)) scripted = 0xff;
        put_s(&l, "t=");
        put_u64(&l, t, 2);
        put_c(&l, ' ');
        const char *name = o.action < GMAN_NUM_ACTIONS ? ACTION_NAMES[o.action] : "?";
        size_t w = 0;
        for (; name[w]; w++) put_c(&l, name[w]);
        for (; w < 11; w++) put_c(&l, ' ');
        put_s(&l, " p=[");
        for (int i = 0; i < GMAN_NUM_ACTIONS; i++) {
            if (i) put_c(&l, ' ');
            put_bits(&l, o.probs[i]);
        }
        put_s(&l, "] v=");
        put_bits(&l, o.value);
        put_s(&l, " adapted=");
        put_u64(&l, o.adapted, 0);
        put_s(&l, " adaptations=");
        put_u64(&l, cn.adaptations, 0);
        put_s(&l, " rollbacks=");
        put_u64(&l, cn.rollbacks, 0);
        put_s(&l, " (script ");
        put_s(&l, scripted < GMAN_NUM_ACTIONS ? ACTION_NAMES[scripted] : "?");
        put_c(&l, ')');
        emit(io, &l);
        if (o.adapted) {
            gman_adapt_report r;
            TRY(gman_last_adaptation(nav, &r));
            put_s(&l, "  inner update: L_D=");
            put_bits(&l, r.ld_loss);
            put_s(&l, " E[D(s)]=");
            put_bits(&l, r.ld_mean_real);
            put_s(&l, " E[D(x)]=");
            put_bits(&l, r.ld_mean_fake);
            put_s(&l, " penalty=");
            put_bits(&l, r.ld_penalty);
            put_s(&l, " L_ad=");
            put_bits(&l, r.adapt_loss);
            put_s(&l, " D applied=");
            put_bool(&l, r.disc_applied);
            put_s(&l, " G/actor applied=");
            put_bool(&l, r.adapt_applied);
            emit(io, &l);
            TRY(gman_generator_output(nav, zero_z, info.noise, gx, FEAT));
            put_s(&l, "  G(SE(y), 0) moved by ");
            put_fixed6(&l, norm_from(gx, g0, FEAT));
            put_s(&l, " since the episode began");
            emit(io, &l);
        }
    }
    gman_counters cn;
    TRY(gman_get_counters(nav, &cn));
    TRY(gman_generated_feature(nav, gx, FEAT));
    uint32_t sum = 0;
    for (int i = 0; i < FEAT; i++) sum += bits(gx[i]);
    put_s(&l, "done: steps=");
    put_u64(&l, cn.steps, 0);
    put_s(&l, " adaptations=");
    put_u64(&l, cn.adaptations, 0);
    put_s(&l, " rollbacks=");
    put_u64(&l, cn.rollbacks, 0);
    put_s(&l, " x_t bit-sum=");
    put_hex8(&l, sum);
    emit(io, &l);
    return 0;
}
