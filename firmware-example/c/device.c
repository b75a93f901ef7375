/*
 * The C firmware for QEMU mps2-an386 (Cortex-M4F): the recorded episode through the C API,
 * printed over semihosting, then OK and a successful exit (failure on any error or fault).
 * No libc: start-up, semihosting and formatting are here and in episode.c.
 *
 * The blob is the one the Rust firmware embeds (blob.S, read in place from flash); the arena
 * is a static array of GMAN_ARENA_BYTES_MCU_MAP3X3 bytes, sized at compile time.
 */
#include <stdint.h>

#include "episode.h"
#include "gman.h"

/* ---- semihosting (ARM "Angel" calls through bkpt 0xAB) ---- */
static int semihost(int op, const void *arg) {
    register int r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}
#define SYS_OPEN 0x01
#define SYS_CLOSE 0x02
#define SYS_WRITE0 0x04
#define SYS_WRITE 0x05
#define SYS_READ 0x06
#define SYS_SEEK 0x0A
#define SYS_FLEN 0x0C
#define SYS_EXIT 0x18
#define ADP_STOPPED_APPLICATION_EXIT 0x20026
#define ADP_STOPPED_RUN_TIME_ERROR 0x20023

/* Output goes to the host's stdout: ":tt" opened for writing, as the Rust firmware's
   hprintln does (SYS_WRITE0 would go to QEMU's console instead). */
static int stdout_fd = -1;
static void write0(const char *s) {
    if (stdout_fd < 0) {
        static const char tt[] = ":tt";
        int a[3] = {(int)(uintptr_t)tt, 4 /* "w" */, 3};
        stdout_fd = semihost(SYS_OPEN, a);
    }
    size_t n = 0;
    while (s[n]) n++;
    int w[3] = {stdout_fd, (int)(uintptr_t)s, (int)n};
    if (stdout_fd < 0 || semihost(SYS_WRITE, w) != 0) semihost(SYS_WRITE0, s);
}
static void sh_exit(int ok) {
    semihost(SYS_EXIT, (const void *)(uintptr_t)(ok ? ADP_STOPPED_APPLICATION_EXIT
                                                    : ADP_STOPPED_RUN_TIME_ERROR));
    for (;;) {
    }
}

typedef struct host_file {
    int fd;
} host_file;

static long hf_len(void *ctx) {
    int a[1] = {((host_file *)ctx)->fd};
    return semihost(SYS_FLEN, a);
}
static int hf_read(void *ctx, size_t off, uint8_t *buf, size_t n) {
    int fd = ((host_file *)ctx)->fd;
    int s[2] = {fd, (int)off};
    if (semihost(SYS_SEEK, s) != 0) return 1;
    int r[3] = {fd, (int)(uintptr_t)buf, (int)n};
    /* SYS_READ returns the number of bytes it did not read. */
    return semihost(SYS_READ, r) != 0;
}
static void hf_line(void *ctx, const char *text) {
    (void)ctx;
    write0(text);
    write0("\n");
}

extern const uint8_t gman_blob[];
extern const uint8_t gman_blob_end[];

/* The navigator's RAM: handle and state, sized at compile time for the blob's preset. */
static uint8_t arena[GMAN_ARENA_BYTES_MCU_MAP3X3];

int main(void) {
    const uint8_t *blob = gman_blob;
    size_t blob_len = (size_t)(gman_blob_end - gman_blob);
    size_t need = 0;
    gman_status s = gman_arena_size(blob, blob_len, &need);
    if (s != GMAN_OK) {
        write0("ERROR: blob: ");
        write0(gman_status_str(s));
        write0("\n");
        return 1;
    }
    if (need > sizeof arena) {
        write0("ERROR: the blob needs a larger arena than GMAN_ARENA_BYTES_MCU_MAP3X3\n");
        return 1;
    }
    static const char path[] = "data/episode.gmep";
    int open_args[3] = {(int)(uintptr_t)path, 1 /* "rb" */, (int)(sizeof path - 1)};
    host_file f = {semihost(SYS_OPEN, open_args)};
    if (f.fd < 0) {
        write0("ERROR: cannot open data/episode.gmep on the host (run QEMU in firmware-example/)\n");
        return 1;
    }
    ep_io io = {&f, hf_len, hf_read, hf_line};
    const char *err = ep_run(blob, blob_len, arena, sizeof arena, 0, &io);
    int close_args[1] = {f.fd};
    semihost(SYS_CLOSE, close_args);
    if (err) {
        write0("ERROR: ");
        write0(err);
        write0("\n");
        return 1;
    }
    write0("OK\n");
    return 0;
}

/* ---- start-up ---- */
extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;

void Reset_Handler(void) {
    uint32_t *src = &_sidata, *dst = &_sdata;
    while (dst < &_edata) *dst++ = *src++;
    for (dst = &_sbss; dst < &_ebss;) *dst++ = 0;
    /* Enable the FPU (CP10, CP11 full access) before any float instruction. */
    volatile uint32_t *cpacr = (volatile uint32_t *)0xE000ED88u;
    *cpacr |= 0xFu << 20;
    __asm__ volatile("dsb\n isb" ::: "memory");
    sh_exit(main() == 0);
}

void Fault_Handler(void) {
    write0("HardFault\n");
    sh_exit(0);
}

__attribute__((section(".vectors"), used)) static const void *const vectors[16] = {
    &_estack,      Reset_Handler, Fault_Handler, Fault_Handler,
    Fault_Handler, Fault_Handler, Fault_Handler, 0,
    0,             0,             0,             Fault_Handler,
    Fault_Handler, 0,             Fault_Handler, Fault_Handler,
};

/* memcpy/memset for the compiler's own calls (no libc). */
void *memcpy(void *d, const void *s, size_t n) {
    uint8_t *dd = d;
    const uint8_t *ss = s;
    while (n--) *dd++ = *ss++;
    return d;
}
void *memset(void *d, int c, size_t n) {
    uint8_t *dd = d;
    while (n--) *dd++ = (uint8_t)c;
    return d;
}
