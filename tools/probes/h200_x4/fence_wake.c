/* vkWaitForFences, and the CLOCK_MONOTONIC time it returned at: read in C, before the calling
 * Python thread has the interpreter again (experiments/h200_x4/fence_wake.py). */
#include <stdint.h>
#include <time.h>

typedef int32_t (*wait_fn)(void *, uint32_t, const void *, uint32_t, uint64_t);

int32_t wait_stamped(wait_fn fn, void *device, uint32_t count, const void *fences,
                     uint32_t all, uint64_t timeout, int64_t *returned_ns) {
    int32_t result = fn(device, count, fences, all, timeout);
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    *returned_ns = (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
    return result;
}
