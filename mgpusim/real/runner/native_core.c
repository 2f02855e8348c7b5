/* The runner's hot loops in native threads: per VkQueue a submit and a reap thread, a host-copy
 * dispatcher and K memcpy threads, as mgpusim/real/runner/executor.py runs them in Python.
 *
 * Why: with light 4-GPU frames the Python runner's sixteen threads keep the interpreter busy, and
 * a thread the driver woke from a fence wait then waits 0.08-0.15 ms (median) for the interpreter
 * before it can hand on: the frame measured the runner, not the schedule. Here no hand-off needs
 * the interpreter. Python plans everything first (native.py): the recorded command buffers, the
 * semaphores, the host copies' byte ranges, and every wait as an edge to an earlier node; this
 * file only follows the edges.
 *
 * A node's edges: DONE (its producer finished: a fence, or a host copy's last part), SUBMITTED
 * (the binary-semaphore rule: the producer is submitted first) and REAPED (the producer's
 * command buffer and fence were read and reset: the node reuses them). Flags are 32-bit words
 * that waiting threads sleep on with futex, each on its own word.
 *
 * Times are CLOCK_MONOTONIC nanoseconds (Python's time.monotonic_ns); GPU timestamps are left in
 * device ticks for Python to put on that clock. Linux only (futex). */
#define _GNU_SOURCE
#include <errno.h>
#include <limits.h>
#include <linux/futex.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

/* The node table's columns (int64 each); keep in step with native.py's COLUMNS. */
enum { C_KIND, C_QUEUE, C_DEVICE, C_CMD, C_FENCE, C_POOL, C_STAMPS, C_WAIT_OFF, C_WAIT_N,
       C_SIGNAL_OFF, C_SIGNAL_N, C_DEP_OFF, C_DEP_N, C_PART_OFF, C_PART_N, N_COLS };
enum { KIND_GPU = 0, KIND_HOST = 1 };
enum { EDGE_DONE = 0, EDGE_SUBMITTED = 1, EDGE_REAPED = 2 };
enum { STREAM_GPU = 0, STREAM_HOST = 1 };
/* The outputs per node: when the thread saw the inputs, called the driver (or queued the parts),
 * had returned; the two device timestamps. */
enum { O_SEEN, O_CALL, O_CALLED, O_TICK0, O_TICK1, N_OUT };
/* error kinds, and the Vulkan call that failed, read by native.py */
enum { ERR_NONE = 0, ERR_VULKAN = 1, ERR_STUCK = 2, ERR_DEVICE = 3, ERR_THREAD = 4 };
enum { CALL_NONE = -1, CALL_SUBMIT = 0, CALL_WAIT = 1, CALL_RESET = 2, CALL_QUERY = 3 };

#define VK_SUCCESS 0
#define VK_TIMEOUT 2
#define STRUCTURE_TYPE_SUBMIT_INFO 4
#define PIPELINE_STAGE_ALL_COMMANDS 0x00010000u
#define QUERY_RESULT_64_WAIT 3u
#define SLICE_NS 50000000LL /* how often a waiting thread looks at the abort flag */
#define MAX_WAITS 64

typedef int32_t (*submit_fn)(void *queue, uint32_t count, const void *infos, void *fence);
typedef int32_t (*wait_fn)(void *device, uint32_t count, const void *fences, uint32_t all,
                           uint64_t timeout);
typedef int32_t (*reset_fn)(void *device, uint32_t count, const void *fences);
typedef int32_t (*query_fn)(void *device, void *pool, uint32_t first, uint32_t count, size_t size,
                            void *data, uint64_t stride, uint32_t flags);

typedef struct { /* VkSubmitInfo */
    int32_t sType;
    const void *pNext;
    uint32_t waitSemaphoreCount;
    const int64_t *pWaitSemaphores;
    const uint32_t *pWaitDstStageMask;
    uint32_t commandBufferCount;
    const int64_t *pCommandBuffers;
    uint32_t signalSemaphoreCount;
    const int64_t *pSignalSemaphores;
} submit_info;

typedef struct {
    atomic_int submitted, done, reaped, watching, parts_left;
} node_state;

typedef struct {
    submit_fn submit;
    wait_fn wait;
    reset_fn reset;
    query_fn query;
    int64_t *nodes;       /* N x N_COLS */
    const int64_t *sems;  /* semaphore handles, by C_WAIT_OFF / C_SIGNAL_OFF */
    const int64_t *deps;  /* (producer node, edge) pairs, by C_DEP_OFF */
    const int64_t *parts; /* (dst, src, bytes) triples, by C_PART_OFF */
    int64_t *out;         /* N x N_OUT */
    int64_t *part_out;    /* P x 3: start, end, memcpy thread */
    int64_t stall_ns;
    node_state *state;
    atomic_int abort;
    atomic_int error_claimed;
    int64_t *error; /* kind, node, other node, VkResult, call */
    /* the memcpy threads' queue of part indices (-1: stop) */
    pthread_mutex_t parts_mu;
    pthread_cond_t parts_cv;
    int64_t *part_queue;
    int64_t part_head, part_tail, part_cap;
} run_t;

typedef struct {
    run_t *run;
    const int64_t *nodes; /* the stream's node indices, in order */
    int64_t count;
    int64_t worker;
} job_t;

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void futex_wait(atomic_int *word, int value, int64_t ns) {
    struct timespec ts = {ns / 1000000000LL, ns % 1000000000LL};
    syscall(SYS_futex, (int *)word, FUTEX_WAIT_PRIVATE, value, &ts, NULL, 0);
}

static void set_flag(atomic_int *word) {
    atomic_store(word, 1);
    syscall(SYS_futex, (int *)word, FUTEX_WAKE_PRIVATE, INT_MAX, NULL, NULL, 0);
}

static int64_t col(const run_t *r, int64_t node, int c) { return r->nodes[node * N_COLS + c]; }

/* The first error wins; every thread then stops at its next look at `abort`. */
static void fail(run_t *r, int64_t kind, int64_t node, int64_t other, int64_t result,
                 int64_t call) {
    if (atomic_exchange(&r->error_claimed, 1) == 0) {
        r->error[0] = kind;
        r->error[1] = node;
        r->error[2] = other;
        r->error[3] = result;
        r->error[4] = call;
    }
    atomic_store(&r->abort, 1);
    pthread_mutex_lock(&r->parts_mu);
    pthread_cond_broadcast(&r->parts_cv);
    pthread_mutex_unlock(&r->parts_mu);
}

/* Sleep until `word` is set; -1 if the run aborted or `who` waited past the stall limit. */
static int wait_flag(run_t *r, atomic_int *word, int64_t who, int64_t other) {
    if (atomic_load(word)) return 0;
    int64_t deadline = now_ns() + r->stall_ns;
    while (!atomic_load(word)) {
        if (atomic_load(&r->abort)) return -1;
        int64_t left = deadline - now_ns();
        if (left <= 0) {
            fail(r, ERR_STUCK, who, other, 0, CALL_NONE);
            return -1;
        }
        futex_wait(word, 0, left < SLICE_NS ? left : SLICE_NS);
    }
    return 0;
}

/* Wait for GPU node `p`'s fence. One thread at a time waits in the driver (`watching`); the
 * others sleep on `done`, which it sets. Why: with several threads inside vkWaitForFences on one
 * fence, the NVIDIA driver (580, four H200s) woke one of them at the signal and the others about
 * 9 ms later (a light sort-first frame went from 2.1 to 11 ms every few frames). The Python
 * executor's Submission.finished keeps one watcher for the same reason. The reap thread resets
 * the fence only once no thread watches it: a thread takes the watch, then looks at `done`; the
 * reaper sets `done`, then looks at the watch. */
static int wait_fence(run_t *r, int64_t p, int64_t who) {
    node_state *s = &r->state[p];
    int64_t deadline = now_ns() + r->stall_ns;
    void *device = (void *)col(r, p, C_DEVICE);
    const int64_t *fence = &r->nodes[p * N_COLS + C_FENCE];
    while (!atomic_load(&s->done)) {
        if (atomic_load(&r->abort)) return -1;
        if (now_ns() > deadline) {
            fail(r, ERR_DEVICE, who, p, 0, CALL_WAIT);
            return -1;
        }
        int idle = 0;
        if (!atomic_compare_exchange_strong(&s->watching, &idle, 1)) {
            futex_wait(&s->done, 0, SLICE_NS); /* the watcher wakes us */
            continue;
        }
        int rc = 0;
        while (!rc && !atomic_load(&s->done)) {
            int32_t res = r->wait(device, 1, fence, 1, SLICE_NS);
            if (res == VK_SUCCESS) {
                set_flag(&s->done);
            } else if (res != VK_TIMEOUT) {
                fail(r, ERR_VULKAN, who, p, res, CALL_WAIT);
                rc = -1;
            } else if (atomic_load(&r->abort)) {
                rc = -1;
            } else if (now_ns() > deadline) {
                fail(r, ERR_DEVICE, who, p, 0, CALL_WAIT);
                rc = -1;
            }
        }
        atomic_store(&s->watching, 0);
        return rc;
    }
    return 0;
}

/* Block until node `p` finished: a GPU node's fence (once submitted), a host copy's last part. */
static int wait_done(run_t *r, int64_t p, int64_t who) {
    node_state *s = &r->state[p];
    if (atomic_load(&s->done)) return 0;
    if (col(r, p, C_KIND) == KIND_HOST) return wait_flag(r, &s->done, who, p);
    if (wait_flag(r, &s->submitted, who, p)) return -1;
    return wait_fence(r, p, who);
}

static int wait_inputs(run_t *r, int64_t n) {
    const int64_t *d = r->deps + 2 * col(r, n, C_DEP_OFF);
    for (int64_t k = 0; k < col(r, n, C_DEP_N); k++) {
        int64_t p = d[2 * k], edge = d[2 * k + 1];
        int rc;
        if (edge == EDGE_DONE) rc = wait_done(r, p, n);
        else if (edge == EDGE_SUBMITTED) rc = wait_flag(r, &r->state[p].submitted, n, p);
        else rc = wait_flag(r, &r->state[p].reaped, n, p);
        if (rc) return -1;
    }
    return 0;
}

static void *submit_stream(void *arg) {
    job_t *job = arg;
    run_t *r = job->run;
    uint32_t stages[MAX_WAITS];
    for (int k = 0; k < MAX_WAITS; k++) stages[k] = PIPELINE_STAGE_ALL_COMMANDS;
    for (int64_t i = 0; i < job->count; i++) {
        int64_t n = job->nodes[i];
        if (wait_inputs(r, n)) return NULL;
        int64_t *o = r->out + n * N_OUT;
        o[O_SEEN] = now_ns();
        submit_info info = {0};
        info.sType = STRUCTURE_TYPE_SUBMIT_INFO;
        info.waitSemaphoreCount = (uint32_t)col(r, n, C_WAIT_N);
        info.pWaitSemaphores = r->sems + col(r, n, C_WAIT_OFF);
        info.pWaitDstStageMask = stages;
        info.commandBufferCount = 1;
        info.pCommandBuffers = &r->nodes[n * N_COLS + C_CMD];
        info.signalSemaphoreCount = (uint32_t)col(r, n, C_SIGNAL_N);
        info.pSignalSemaphores = r->sems + col(r, n, C_SIGNAL_OFF);
        o[O_CALL] = now_ns();
        int32_t res = r->submit((void *)col(r, n, C_QUEUE), 1, &info, (void *)col(r, n, C_FENCE));
        o[O_CALLED] = now_ns();
        if (res != VK_SUCCESS) {
            fail(r, ERR_VULKAN, n, -1, res, CALL_SUBMIT);
            return NULL;
        }
        set_flag(&r->state[n].submitted);
    }
    return NULL;
}

/* In queue order: each node's fence, its timestamps, then the fence reset for the next use. */
static void *reap_stream(void *arg) {
    job_t *job = arg;
    run_t *r = job->run;
    for (int64_t i = 0; i < job->count; i++) {
        int64_t n = job->nodes[i];
        node_state *s = &r->state[n];
        if (wait_flag(r, &s->submitted, n, n) || wait_fence(r, n, n)) return NULL;
        int64_t *o = r->out + n * N_OUT;
        void *device = (void *)col(r, n, C_DEVICE);
        const uint64_t *stamps = (const uint64_t *)col(r, n, C_STAMPS);
        if (stamps) {
            o[O_TICK0] = (int64_t)stamps[0];
            o[O_TICK1] = (int64_t)stamps[1];
        } else {
            uint64_t ticks[2];
            int32_t res = r->query(device, (void *)col(r, n, C_POOL), 0, 2, sizeof ticks, ticks, 8,
                                   QUERY_RESULT_64_WAIT);
            if (res != VK_SUCCESS) {
                fail(r, ERR_VULKAN, n, -1, res, CALL_QUERY);
                return NULL;
            }
            o[O_TICK0] = (int64_t)ticks[0];
            o[O_TICK1] = (int64_t)ticks[1];
        }
        while (atomic_load(&s->watching)) sched_yield(); /* it returns at once: signalled */
        int32_t res = r->reset(device, 1, &r->nodes[n * N_COLS + C_FENCE]);
        if (res != VK_SUCCESS) {
            fail(r, ERR_VULKAN, n, -1, res, CALL_RESET);
            return NULL;
        }
        set_flag(&s->reaped);
    }
    return NULL;
}

static void push_part(run_t *r, int64_t part) {
    pthread_mutex_lock(&r->parts_mu);
    r->part_queue[r->part_tail++ % r->part_cap] = part;
    pthread_cond_signal(&r->parts_cv);
    pthread_mutex_unlock(&r->parts_mu);
}

/* The host copies in order: once a copy's inputs finished, its parts go to the memcpy threads. */
static void *host_dispatch(void *arg) {
    job_t *job = arg;
    run_t *r = job->run;
    for (int64_t i = 0; i < job->count && !atomic_load(&r->abort); i++) {
        int64_t n = job->nodes[i];
        if (wait_inputs(r, n)) break;
        int64_t *o = r->out + n * N_OUT;
        o[O_SEEN] = now_ns();
        int64_t first = col(r, n, C_PART_OFF), count = col(r, n, C_PART_N);
        atomic_store(&r->state[n].parts_left, (int)count);
        set_flag(&r->state[n].submitted);
        o[O_CALL] = now_ns();
        if (count == 0) set_flag(&r->state[n].done);
        for (int64_t k = 0; k < count; k++) push_part(r, first + k);
        o[O_CALLED] = now_ns();
    }
    for (int64_t k = 0; k < job->worker; k++) push_part(r, -1); /* worker: the threads to stop */
    return NULL;
}

static void *memcpy_worker(void *arg) {
    job_t *job = arg;
    run_t *r = job->run;
    for (;;) {
        pthread_mutex_lock(&r->parts_mu);
        while (r->part_head == r->part_tail && !atomic_load(&r->abort))
            pthread_cond_wait(&r->parts_cv, &r->parts_mu);
        if (r->part_head == r->part_tail) { /* aborted */
            pthread_mutex_unlock(&r->parts_mu);
            return NULL;
        }
        int64_t part = r->part_queue[r->part_head++ % r->part_cap];
        pthread_mutex_unlock(&r->parts_mu);
        if (part < 0) return NULL;
        const int64_t *p = r->parts + 3 * part;
        int64_t *o = r->part_out + 3 * part;
        o[0] = now_ns();
        memcpy((void *)p[0], (const void *)p[1], (size_t)p[2]);
        o[1] = now_ns();
        o[2] = job->worker;
        int64_t n = job->nodes[part]; /* the part's node */
        if (atomic_fetch_sub(&r->state[n].parts_left, 1) == 1) set_flag(&r->state[n].done);
    }
}

/* Run every node. `stream_off` (streams + 1 entries) cuts `stream_nodes` into streams of kind
 * `stream_kind`; `part_node` names each part's node. Returns 0, or the error kind with
 * `error` = (kind, node, other node, VkResult, call). */
int mgpusim_run(void *submit, void *wait, void *reset, void *query, int64_t *nodes, int64_t count,
                const int64_t *sems, const int64_t *deps, const int64_t *parts, int64_t part_count,
                const int64_t *part_node, const int64_t *stream_nodes, const int64_t *stream_off,
                const int64_t *stream_kind, int64_t streams, int64_t host_threads, int64_t stall_ns,
                int64_t *out, int64_t *part_out, int64_t *error) {
    run_t r;
    memset(&r, 0, sizeof r);
    r.submit = (submit_fn)submit;
    r.wait = (wait_fn)wait;
    r.reset = (reset_fn)reset;
    r.query = (query_fn)query;
    r.nodes = nodes;
    r.sems = sems;
    r.deps = deps;
    r.parts = parts;
    r.out = out;
    r.part_out = part_out;
    r.stall_ns = stall_ns;
    r.error = error;
    r.part_cap = part_count + host_threads + 1;
    r.state = calloc((size_t)(count ? count : 1), sizeof *r.state);
    r.part_queue = calloc((size_t)r.part_cap, sizeof *r.part_queue);
    job_t *jobs = calloc((size_t)(2 * streams + host_threads + 1), sizeof *jobs);
    pthread_t *threads = calloc((size_t)(2 * streams + host_threads + 1), sizeof *threads);
    if (!r.state || !r.part_queue || !jobs || !threads) {
        free(r.state); free(r.part_queue); free(jobs); free(threads);
        error[0] = ERR_THREAD;
        return ERR_THREAD;
    }
    pthread_mutex_init(&r.parts_mu, NULL);
    pthread_cond_init(&r.parts_cv, NULL);
    for (int64_t i = 0; i < count; i++) {
        int64_t d = nodes[i * N_COLS + C_WAIT_N];
        if (d > MAX_WAITS) { fail(&r, ERR_THREAD, i, -1, d, CALL_NONE); break; }
    }
    int started = 0;
    for (int64_t s = 0; s < streams && !atomic_load(&r.abort); s++) {
        const int64_t *list = stream_nodes + stream_off[s];
        int64_t n = stream_off[s + 1] - stream_off[s];
        if (stream_kind[s] == STREAM_GPU) {
            jobs[started] = (job_t){&r, list, n, 0};
            if (pthread_create(&threads[started], NULL, submit_stream, &jobs[started])) break;
            started++;
            jobs[started] = (job_t){&r, list, n, 0};
            if (pthread_create(&threads[started], NULL, reap_stream, &jobs[started])) break;
            started++;
        } else {
            jobs[started] = (job_t){&r, list, n, host_threads};
            if (pthread_create(&threads[started], NULL, host_dispatch, &jobs[started])) break;
            started++;
            for (int64_t k = 0; k < host_threads; k++) {
                jobs[started] = (job_t){&r, part_node, 0, k};
                if (pthread_create(&threads[started], NULL, memcpy_worker, &jobs[started])) break;
                started++;
            }
        }
    }
    int64_t expected = 0;
    for (int64_t s = 0; s < streams; s++) expected += stream_kind[s] == STREAM_GPU ? 2 : 1 + host_threads;
    if (started < expected) fail(&r, ERR_THREAD, -1, -1, errno, CALL_NONE);
    for (int i = 0; i < started; i++) pthread_join(threads[i], NULL);
    pthread_cond_destroy(&r.parts_cv);
    pthread_mutex_destroy(&r.parts_mu);
    free(r.state);
    free(r.part_queue);
    free(jobs);
    free(threads);
    return (int)error[0];
}
