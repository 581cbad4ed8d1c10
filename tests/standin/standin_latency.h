/*
 * The read-to-command latency histogram of the device stand-ins (hd_standin.c, dhd_standin.c):
 * from the moment the device's state was read to the moment the force answering it was sent,
 * in 1 µs bins up to LATENCY_BINS µs (beyond: one overflow bin). Header-only; each stand-in
 * keeps one in its own state, under its own lock.
 */

#ifndef STANDIN_LATENCY_H
#define STANDIN_LATENCY_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#define LATENCY_BINS 2000

typedef struct {
    uint64_t hist[LATENCY_BINS + 1];
    uint64_t count;
    double max_us;
} Latency;

static void latency_record(Latency *l, double us) {
    int bin = us < 0.0 ? 0 : (us >= LATENCY_BINS ? LATENCY_BINS : (int)us);
    l->hist[bin] += 1;
    l->count += 1;
    if (us > l->max_us) l->max_us = us;
}

/* The percentile's bin's upper edge, never above the largest latency seen. */
static double latency_percentile(const Latency *l, double p) {
    if (l->count == 0) return 0.0;
    uint64_t rank = (uint64_t)ceil(p * (double)l->count);
    if (rank == 0) rank = 1;
    uint64_t seen = 0;
    for (int bin = 0; bin < LATENCY_BINS; bin++) {
        seen += l->hist[bin];
        if (seen >= rank) {
            double edge = (double)(bin + 1);
            return edge < l->max_us ? edge : l->max_us;
        }
    }
    return l->max_us; /* in the overflow bin */
}

/* The median, the 99th percentile, the largest (µs) and the count, each written when not NULL. */
static void latency_summary(const Latency *l, double *p50_us, double *p99_us, double *max_us,
                            unsigned long long *count) {
    if (p50_us != NULL) *p50_us = latency_percentile(l, 0.50);
    if (p99_us != NULL) *p99_us = latency_percentile(l, 0.99);
    if (max_us != NULL) *max_us = l->max_us;
    if (count != NULL) *count = l->count;
}

static void latency_reset(Latency *l) { memset(l, 0, sizeof(*l)); }

#endif
