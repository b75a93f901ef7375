/*
 * The recorded episode through the C API on the host: host MODEL.gman EPISODE.gmep.
 * Prints the Rust firmware's result lines, then OK. The arena is deliberately misaligned
 * (the library aligns it), and a second navigator in a second arena runs the same episode
 * while the first one's arena is still live: both must print the same lines. A third runs
 * it on the background schedule (its inner updates computed by gman_adapt_slice between
 * the steps): the same lines but for the one naming the schedule.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "episode.h"
#include "gman.h"

typedef struct file {
    uint8_t *bytes;
    long len;
    char **lines;
    size_t n;
} file;

static long f_len(void *ctx) { return ((file *)ctx)->len; }
static int f_read(void *ctx, size_t off, uint8_t *buf, size_t n) {
    file *f = ctx;
    if (off > (size_t)f->len || n > (size_t)f->len - off) return 1;
    memcpy(buf, f->bytes + off, n);
    return 0;
}
static void f_line(void *ctx, const char *text) {
    file *f = ctx;
    f->lines = realloc(f->lines, (f->n + 1) * sizeof *f->lines);
    f->lines[f->n] = malloc(strlen(text) + 1);
    strcpy(f->lines[f->n++], text);
}

static uint8_t *slurp(const char *path, long *len) {
    FILE *fp = fopen(path, "rb");
    if (!fp) return NULL;
    fseek(fp, 0, SEEK_END);
    *len = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    uint8_t *b = malloc((size_t)*len + 1);
    if (fread(b, 1, (size_t)*len, fp) != (size_t)*len) {
        fclose(fp);
        free(b);
        return NULL;
    }
    fclose(fp);
    return b;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s MODEL.gman EPISODE.gmep\n", argv[0]);
        return 2;
    }
    long blob_len = 0;
    uint8_t *blob = slurp(argv[1], &blob_len);
    file ep = {0};
    ep.bytes = slurp(argv[2], &ep.len);
    if (!blob || !ep.bytes) {
        fprintf(stderr, "ERROR: cannot read %s\n", !blob ? argv[1] : argv[2]);
        return 1;
    }
    size_t need = 0;
    gman_status s = gman_arena_size(blob, (size_t)blob_len, &need);
    if (s != GMAN_OK) {
        fprintf(stderr, "ERROR: %s: %s\n", argv[1], gman_status_str(s));
        return 1;
    }
    /* Two arenas, each one byte off any alignment. */
    uint8_t *a1 = malloc(need + 1), *a2 = malloc(need + 1);
    ep_io io1 = {&ep, f_len, f_read, f_line};
    const char *err = ep_run(blob, (size_t)blob_len, a1 + 1, need, 0, &io1);
    if (err) {
        printf("ERROR: %s\n", err);
        return 1;
    }
    file ep2 = {ep.bytes, ep.len, NULL, 0};
    ep_io io2 = {&ep2, f_len, f_read, f_line};
    err = ep_run(blob, (size_t)blob_len, a2 + 1, need, 0, &io2);
    if (err) {
        printf("ERROR: second navigator: %s\n", err);
        return 1;
    }
    if (ep2.n != ep.n) {
        printf("ERROR: the second navigator printed %zu lines, the first %zu\n", ep2.n, ep.n);
        return 1;
    }
    for (size_t i = 0; i < ep.n; i++) {
        if (strcmp(ep.lines[i], ep2.lines[i])) {
            printf("ERROR: line %zu differs between the two navigators\n", i);
            return 1;
        }
        printf("%s\n", ep.lines[i]);
    }
    file ep3 = {ep.bytes, ep.len, NULL, 0};
    ep_io io3 = {&ep3, f_len, f_read, f_line};
    uint8_t *a3 = malloc(need);
    err = ep_run(blob, (size_t)blob_len, a3, need, 2, &io3);
    if (err) {
        printf("ERROR: background navigator: %s\n", err);
        return 1;
    }
    if (ep3.n != ep.n) {
        printf("ERROR: the background navigator printed %zu lines, the automatic %zu\n", ep3.n,
               ep.n);
        return 1;
    }
    size_t schedule_lines = 0;
    for (size_t i = 0; i < ep.n; i++) {
        if (!strncmp(ep.lines[i], "schedule: ", 10)) {
            schedule_lines++;
            if (strncmp(ep3.lines[i], "schedule: Background,", 21)) {
                printf("ERROR: line %zu of the background run: %s\n", i, ep3.lines[i]);
                return 1;
            }
        } else if (strcmp(ep.lines[i], ep3.lines[i])) {
            printf("ERROR: line %zu differs on the background schedule:\n%s\n%s\n", i,
                   ep.lines[i], ep3.lines[i]);
            return 1;
        }
    }
    if (schedule_lines != 1) {
        printf("ERROR: %zu schedule lines\n", schedule_lines);
        return 1;
    }
    /* An arena one byte short is refused. */
    gman_nav *nav = NULL;
    s = gman_init(blob, (size_t)blob_len, a2, need - 1, NULL, &nav);
    if (s != GMAN_ERR_ARENA_TOO_SMALL || nav) {
        printf("ERROR: a short arena gave %s\n", gman_status_str(s));
        return 1;
    }
    printf("OK\n");
    return 0;
}
