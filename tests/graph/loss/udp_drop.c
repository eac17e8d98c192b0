/* A reproducible UDP loss injector for the test suite (LD_PRELOAD; this kernel has no netem).
 *
 * Every UDP datagram a process sends (sendmsg / sendto / send on a SOCK_DGRAM socket) is dropped with
 * probability DEM_UDP_DROP (0..1; unset or 0: nothing is dropped), from a per-thread xorshift sequence
 * seeded with DEM_UDP_DROP_SEED (default 1) and the thread's id, so a run's losses are reproducible given its
 * threads' order of sends. A dropped datagram is reported as sent (as the network would lose it). The count of
 * dropped datagrams is printed to stderr at exit ("udp_drop: dropped N of M").
 *
 * Build: cc -shared -fPIC -O2 -o udp_drop.so udp_drop.c -ldl
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <unistd.h>

static double rate = -1.0;
static uint64_t seed = 1;
static atomic_ulong dropped, sent;
static __thread uint64_t state;

static void report(void) {
    if (rate > 0)
        fprintf(stderr, "udp_drop: dropped %lu of %lu\n", (unsigned long)dropped, (unsigned long)sent);
}

static void init(void) {
    if (rate >= 0) return;
    const char *r = getenv("DEM_UDP_DROP"), *s = getenv("DEM_UDP_DROP_SEED");
    seed = s ? strtoull(s, NULL, 10) : 1;
    rate = r ? atof(r) : 0.0;
    atexit(report);
}

static int is_udp(int fd) {
    int type = 0;
    socklen_t len = sizeof type;
    return getsockopt(fd, SOL_SOCKET, SO_TYPE, &type, &len) == 0 && type == SOCK_DGRAM;
}

static int drop(int fd) {
    init();
    if (rate <= 0 || !is_udp(fd)) return 0;
    if (!state) state = (seed * 0x9E3779B97F4A7C15ULL) ^ (uint64_t)syscall(SYS_gettid) ^ 0x5DEECE66DULL;
    state ^= state << 13; state ^= state >> 7; state ^= state << 17;
    atomic_fetch_add(&sent, 1);
    if ((double)(state >> 11) * (1.0 / 9007199254740992.0) < rate) {
        atomic_fetch_add(&dropped, 1);
        return 1;
    }
    return 0;
}

ssize_t sendmsg(int fd, const struct msghdr *m, int flags) {
    static ssize_t (*real)(int, const struct msghdr *, int);
    if (!real) real = dlsym(RTLD_NEXT, "sendmsg");
    if (drop(fd)) {
        ssize_t n = 0;
        for (size_t i = 0; i < m->msg_iovlen; i++) n += (ssize_t)m->msg_iov[i].iov_len;
        return n;
    }
    return real(fd, m, flags);
}

ssize_t sendto(int fd, const void *buf, size_t len, int flags, const struct sockaddr *to, socklen_t tolen) {
    static ssize_t (*real)(int, const void *, size_t, int, const struct sockaddr *, socklen_t);
    if (!real) real = dlsym(RTLD_NEXT, "sendto");
    if (drop(fd)) return (ssize_t)len;
    return real(fd, buf, len, flags, to, tolen);
}

ssize_t send(int fd, const void *buf, size_t len, int flags) {
    static ssize_t (*real)(int, const void *, size_t, int);
    if (!real) real = dlsym(RTLD_NEXT, "send");
    if (drop(fd)) return (ssize_t)len;
    return real(fd, buf, len, flags);
}
