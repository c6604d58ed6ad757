/* The candidate search of the ISO 9283 path accuracy (cosim/tracking/metrics.py,
 * distance_to_polyline) in one call: for every point, the segments of its window that can be
 * nearer than the bounds allow. The distances themselves stay in numpy (_pair_distance2):
 * this only chooses which (point, segment) pairs numpy evaluates, with bounds that have a
 * 1e-9 relative margin, so the minimum is the same number as the numpy search's.
 *
 * Per point i (window: segments lo..hi = clip(i - window .. i + window, 0, last)):
 *   1. balls of `size` consecutive segments (centre, radius holding them whole) touching the
 *      window whose centre lies within reach[i] + radius: only their segments can be nearer
 *      than the own segment (reach[i] = its distance with the margin);
 *   2. the nearest midpoint among those balls' segments inside the window bounds the answer
 *      too (a midpoint lies on its segment): bound = min(reach[i], that distance with margin);
 *   3. every segment of those balls inside the window whose midpoint lies within bound + its
 *      half length is a candidate.
 * Comparisons with NaN are false: a NaN point or bound has no candidates, NaN segments and balls
 * of only NaN segments (NaN radius) are never candidates, as in the numpy search.
 */
#include <math.h>

#define INFLATE (1.0 + 1e-9)

static double squared(const double *p, const double *c)
{
    const double dx = p[0] - c[0], dy = p[1] - c[1], dz = p[2] - c[2];
    return dx * dx + dy * dy + dz * dz;
}

/* Whether ball b (of `size` consecutive segments) can hold a segment within `bound` of p; if so,
 * its segments inside the window lo..hi are *j0..*j1. */
static int ball_in_reach(const double *p, long long b, long long size, long long lo, long long hi, double bound,
                         const double *centre, const double *radius, long long *j0, long long *j1)
{
    const double limit = bound + radius[b];
    if (!(squared(p, centre + 3 * b) <= limit * limit)) return 0;
    *j0 = b * size > lo ? b * size : lo;
    *j1 = b * size + size - 1 < hi ? b * size + size - 1 : hi;
    return 1;
}

/* points (m, 3); mid (segments, 3) midpoints, half (segments) half lengths with the margin;
 * centre (balls, 3), radius (balls): balls of `size` consecutive segments; reach (m): the own
 * segment's bound. Writes at most `capacity` pairs to out_i / out_j (ascending in i, then j)
 * and returns how many there are (call again with more room when that exceeds capacity). */
long long polyline_candidates(const double *points, long long m, const double *mid, const double *half,
                              long long segments, const double *centre, const double *radius, long long balls,
                              long long size, long long window, const double *reach, long long *out_i,
                              long long *out_j, long long capacity)
{
    long long count = 0;
    const long long last = segments - 1;
    for (long long i = 0; i < m; ++i) {
        const double *p = points + 3 * i;
        long long lo = i - window < last ? i - window : last;
        if (lo < 0) lo = 0;
        const long long hi = i + window < last ? i + window : last;
        const long long first = lo / size, final = hi / size;
        double bound = reach[i];
        /* 2. the nearest midpoint inside the window among the balls that can hold a nearer segment */
        double nearest = INFINITY;
        for (long long b = first; b <= final && b < balls; ++b) {
            long long j0, j1;
            if (!ball_in_reach(p, b, size, lo, hi, bound, centre, radius, &j0, &j1)) continue;
            for (long long j = j0; j <= j1; ++j) {
                const double d2 = squared(p, mid + 3 * j);
                if (d2 < nearest) nearest = d2;
            }
        }
        const double tight = sqrt(nearest) * INFLATE + 1e-12;
        if (tight < bound) bound = tight;
        /* 1 + 3. the candidates */
        for (long long b = first; b <= final && b < balls; ++b) {
            long long j0, j1;
            if (!ball_in_reach(p, b, size, lo, hi, bound, centre, radius, &j0, &j1)) continue;
            for (long long j = j0; j <= j1; ++j) {
                const double reachable = bound + half[j];
                if (squared(p, mid + 3 * j) <= reachable * reachable) {
                    if (count < capacity) {
                        out_i[count] = i;
                        out_j[count] = j;
                    }
                    ++count;
                }
            }
        }
    }
    return count;
}
