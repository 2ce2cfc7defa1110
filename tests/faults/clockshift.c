/* A wall-clock step for one process (tests): LD_PRELOAD this library and set CLOCK_SHIFT_NS;
   clock_gettime(CLOCK_REALTIME) answers that many nanoseconds off. The monotonic clock is
   left alone. Built by tests/integration/test_journal_faults.py with the C compiler. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdlib.h>
#include <time.h>

static long long shift_ns;
static int (*real_clock_gettime)(clockid_t, struct timespec *);

int clock_gettime(clockid_t id, struct timespec *ts) {
    if (!real_clock_gettime) {
        const char *s = getenv("CLOCK_SHIFT_NS");
        shift_ns = s ? atoll(s) : 0;
        real_clock_gettime = (int (*)(clockid_t, struct timespec *))dlsym(RTLD_NEXT, "clock_gettime");
    }
    int r = real_clock_gettime(id, ts);
    if (r == 0 && (id == CLOCK_REALTIME || id == CLOCK_REALTIME_COARSE)) {
        long long ns = (long long)ts->tv_sec * 1000000000LL + ts->tv_nsec + shift_ns;
        ts->tv_sec = ns / 1000000000LL;
        ts->tv_nsec = ns % 1000000000LL;
    }
    return r;
}
