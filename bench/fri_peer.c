/*
 * A minimal FRI robot peer for bench/bench_fri_latency.py.
 *
 * It sends prepared monitoring messages to the client at their scheduled times (CLOCK_MONOTONIC,
 * sleeping in ppoll until shortly before each deadline, then spinning) and time-stamps every answer
 * on arrival, matched to its message by the answer's reflectedSequenceCounter. No session logic: the
 * messages (all COMMANDING_ACTIVE) are encoded by the benchmark, which also reads the result.
 *
 * Usage: fri_peer MESSAGES CLIENT_PORT OUT [CPU]
 *   MESSAGES  uint32 count, then per message: uint64 send offset [ns], uint32 sequence counter,
 *             uint32 length, the datagram (little-endian, as written by the benchmark)
 *   OUT       per message: int64 sent [ns], int64 answered [ns] (0: no answer), from the start
 *   CPU       pin the peer to this CPU
 * SCHED_FIFO and mlockall are tried and silently skipped when not permitted.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sched.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static int read_varint(const unsigned char *p, size_t n, size_t *i, uint64_t *v) {
    uint64_t r = 0;
    for (int shift = 0; *i < n && shift < 64; shift += 7) {
        unsigned char b = p[(*i)++];
        r |= (uint64_t)(b & 0x7f) << shift;
        if (!(b & 0x80)) {
            *v = r;
            return 1;
        }
    }
    return 0;
}

/* The header's reflectedSequenceCounter (field 1, then field 3) of a command message; -1 if absent. */
static int64_t reflected(const unsigned char *p, size_t n) {
    size_t i = 0;
    while (i < n) {
        uint64_t key, v, len;
        if (!read_varint(p, n, &i, &key)) return -1;
        switch (key & 7) {
        case 0:
            if (!read_varint(p, n, &i, &v)) return -1;
            break;
        case 1: i += 8; break;
        case 5: i += 4; break;
        case 2:
            if (!read_varint(p, n, &i, &len) || len > n - i) return -1;
            if ((key >> 3) == 1) {
                size_t j = i, end = i + len;
                while (j < end) {
                    uint64_t k2;
                    if (!read_varint(p, end, &j, &k2) || (k2 & 7) != 0 || !read_varint(p, end, &j, &v)) return -1;
                    if ((k2 >> 3) == 3) return (int64_t)v;
                }
                return -1;
            }
            i += len;
            break;
        default: return -1;
        }
    }
    return -1;
}

static uint32_t count, seq0;
static int64_t *answered, t0;

static void drain(int s) {
    unsigned char buf[2048];
    for (;;) {
        ssize_t n = recv(s, buf, sizeof buf, 0);
        if (n < 0) return;
        int64_t t = now_ns() - t0;
        int64_t r = reflected(buf, (size_t)n);
        if (r < 0) continue;
        uint32_t k = (uint32_t)r - seq0;
        if (k < count && answered[k] == 0) answered[k] = t;
    }
}

static void wait_until(int s, int64_t deadline) {
    struct pollfd pfd = {.fd = s, .events = POLLIN};
    for (;;) {
        drain(s);
        int64_t left = deadline - (now_ns() - t0);
        if (left <= 0) return;
        if (left > 80000) { /* sleep until 60 us before the deadline, waking for answers */
            int64_t sleep = left - 60000;
            struct timespec ts = {.tv_sec = sleep / 1000000000, .tv_nsec = sleep % 1000000000};
            ppoll(&pfd, 1, &ts, NULL);
        }
    }
}

static int fail(const char *what) {
    fprintf(stderr, "fri_peer: %s: %s\n", what, strerror(errno));
    return 1;
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: fri_peer MESSAGES CLIENT_PORT OUT [CPU]\n");
        return 2;
    }
    FILE *f = fopen(argv[1], "rb");
    if (!f || fread(&count, 4, 1, f) != 1) return fail(argv[1]);
    uint64_t *offset = calloc(count, 8);
    uint32_t *seq = calloc(count, 4), *len = calloc(count, 4);
    unsigned char **data = calloc(count, sizeof *data);
    int64_t *sent = calloc(count, 8);
    answered = calloc(count, 8);
    for (uint32_t k = 0; k < count; k++) {
        if (fread(&offset[k], 8, 1, f) != 1 || fread(&seq[k], 4, 1, f) != 1 || fread(&len[k], 4, 1, f) != 1)
            return fail("truncated message file");
        data[k] = malloc(len[k]);
        if (fread(data[k], 1, len[k], f) != len[k]) return fail("truncated message file");
    }
    fclose(f);
    seq0 = seq[0];
    if (argc > 4) {
        cpu_set_t set;
        CPU_ZERO(&set);
        CPU_SET(atoi(argv[4]), &set);
        sched_setaffinity(0, sizeof set, &set);
    }
    struct sched_param sp = {.sched_priority = 70};
    sched_setscheduler(0, SCHED_FIFO, &sp);
    mlockall(MCL_CURRENT | MCL_FUTURE);

    int s = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in me = {.sin_family = AF_INET, .sin_port = 0, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    if (s < 0 || bind(s, (struct sockaddr *)&me, sizeof me) < 0) return fail("socket");
    fcntl(s, F_SETFL, O_NONBLOCK);
    struct sockaddr_in to = {.sin_family = AF_INET, .sin_port = htons((uint16_t)atoi(argv[2])),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};

    t0 = now_ns() + 100000000;
    for (uint32_t k = 0; k < count; k++) {
        wait_until(s, (int64_t)offset[k]);
        sendto(s, data[k], len[k], 0, (struct sockaddr *)&to, sizeof to);
        sent[k] = now_ns() - t0;
    }
    wait_until(s, (int64_t)offset[count - 1] + 300000000);

    FILE *out = fopen(argv[3], "wb");
    if (!out) return fail(argv[3]);
    for (uint32_t k = 0; k < count; k++) {
        fwrite(&sent[k], 8, 1, out);
        fwrite(&answered[k], 8, 1, out);
    }
    fclose(out);
    return 0;
}
