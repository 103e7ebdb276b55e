// outlier.cpp: single-sample glitches replaced by NaN (vibid/outlier.h).
#include <vibid/outlier.h>

#include "api_guard.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Relative part of the floor: above float32 rounding (6e-8), far below any glitch that
// matters (docs: vibid/outlier.h).
constexpr double kRelativeFloor = 1e-6;
// Successors a suspect waits for (vibid/outlier.h): the first shows whether it came back,
// the next two whether the signal moves that much anyway (a random held input starting
// from rest: one look ahead took 8.5 % of such starts for a glitch, three 0 of 200).
constexpr std::size_t kLookahead = VIBID_OUTLIER_LOOKAHEAD;

struct Channel {
    double ref = 0.0;      // last accepted value
    bool has_ref = false;
    double scale = 0.0;    // S: peak of the accepted increments, decaying
    double step = HUGE_VAL;  // q: smallest non-zero jump seen, accepted or decided (HUGE_VAL: none)
    bool pending = false;  // the oldest undecided sample is a suspect in this channel
    double jump = 0.0;     // its jump |x - ref|
};

}  // namespace

struct vibid_outlier {
    std::size_t n = 0;
    double K = VIBID_OUTLIER_THRESHOLD_DEFAULT;
    double decay = 1.0;  // exp(-1 / memory)
    std::size_t warmup = VIBID_OUTLIER_WARMUP_DEFAULT;
    std::size_t cap = 0;  // queued samples at most: max(warmup, kLookahead + 1) + 1

    std::vector<Channel> ch;
    // Queue of samples in push order: [0, n_released) were released by the last call,
    // [n_released, n_decided) are decided, [n_decided, n_queued) wait. A sample waits for
    // its successors when it is a suspect in some channel, or for the warm-up's end.
    std::vector<double> vals;          // cap x n, values (outliers already NaN)
    std::vector<unsigned char> out;    // cap x n, 1 = taken out
    std::size_t n_queued = 0, n_decided = 0, n_released = 0;
    bool warm = false;  // the warm-up has ended
    bool suspect_waits = false;  // sample n_decided was tested and waits for its successors
    vibid_outlier_stats stats{};

    double *row(std::size_t i) { return vals.data() + i * n; }
    const double *row(std::size_t i) const { return vals.data() + i * n; }
    unsigned char *mark(std::size_t i) { return out.data() + i * n; }

    double floor_of(const Channel &c) const {
        const double q = std::isfinite(c.step) ? c.step : 0.0;
        return std::max(q, kRelativeFloor * std::fabs(c.ref));
    }

    void accept(Channel &c, double x) {
        if (c.has_ref) {
            const double a = std::fabs(x - c.ref);
            c.scale = std::max(c.scale, a);
            if (a > 0.0) c.step = std::min(c.step, a);
        }
        c.ref = x;
        c.has_ref = true;
    }

    void take_out(std::size_t i, std::size_t k) {
        row(i)[k] = kNaN;
        mark(i)[k] = 1;
    }

    // First look at sample i: accepted values update the history at once; a suspect waits.
    // true if some channel is a suspect.
    bool test(std::size_t i) {
        const double *x = row(i);
        bool any = false;
        for (std::size_t k = 0; k < n; ++k) {
            Channel &c = ch[k];
            c.scale *= decay;
            if (!std::isfinite(x[k])) continue;  // missing: no value to judge
            const double a = c.has_ref ? std::fabs(x[k] - c.ref) : 0.0;
            if (a > K * c.scale && a > K * floor_of(c)) {  // the floor only when it can matter
                c.jump = a;
                c.pending = true;
                any = true;
                ++stats.held;
                continue;
            }
            accept(c, x[k]);
        }
        return any;
    }

    // Decides the suspects of sample i by its successors i + 1 .. i + L queued (fewer at
    // the end of the data); a successor that is missing in a channel ends that channel's.
    void resolve(std::size_t i) {
        const double *x = row(i);
        std::size_t taken = 0;
        for (std::size_t k = 0; k < n; ++k) {
            Channel &c = ch[k];
            if (!c.pending) continue;
            c.pending = false;
            const double y = i + 1 < n_queued ? row(i + 1)[k] : kNaN;
            bool outlier;
            if (!std::isfinite(y)) {
                outlier = true;
                ++stats.unverified;
            } else {
                // how far apart the samples around it lie: the next one from the last
                // accepted, and the next ones from each other
                double m = std::fabs(y - c.ref);
                for (std::size_t j = i + 2; j < n_queued && j <= i + kLookahead; ++j) {
                    const double u = row(j - 1)[k], v = row(j)[k];
                    if (!std::isfinite(v)) break;
                    m = std::max(m, std::fabs(v - u));
                }
                const double a = std::fabs(x[k] - c.ref), b = std::fabs(y - x[k]);
                outlier = std::min(a, b) > K * std::max({c.scale, floor_of(c), m});
            }
            if (outlier) {
                take_out(i, k);
                ++taken;
            } else {
                accept(c, x[k]);
            }
            // The quantisation step is learned from every jump, a glitch's too (after its
            // own decision): else the one-step flickers of a quantised channel at rest,
            // which accepts no increment, would all be taken out; so the first is (when
            // the warm-up saw none), later glitches of that channel need K times its size.
            c.step = std::min(c.step, c.jump);
        }
        count(taken);
    }

    // true when the suspects of sample i have all the successors they can get
    bool can_resolve(std::size_t i) const {
        for (std::size_t k = 0; k < n; ++k) {
            if (!ch[k].pending) continue;
            std::size_t j = i + 1;
            while (j < n_queued && j <= i + kLookahead && std::isfinite(row(j)[k])) ++j;
            if (j <= i + kLookahead && j >= n_queued) return false;  // more may come
        }
        return true;
    }

    void count(std::size_t taken) {
        if (!taken) return;
        ++stats.outlier_samples;
        stats.outlier_values += taken;
    }

    // The end of the warm-up: S from the third-largest increment of the queued samples
    // (one glitch makes two large ones), the quantisation step from their smallest, and
    // the first value of each channel tested against its next two.
    void end_warmup() {
        warm = true;
        for (std::size_t k = 0; k < n; ++k) {
            Channel &c = ch[k];
            double top[3] = {0.0, 0.0, 0.0};
            std::size_t n_inc = 0;
            for (std::size_t i = 1; i < n_queued; ++i) {
                const double u = row(i - 1)[k], v = row(i)[k];
                if (!std::isfinite(u) || !std::isfinite(v)) continue;
                const double a = std::fabs(v - u);
                ++n_inc;
                if (a > 0.0) c.step = std::min(c.step, a);
                if (a > top[0]) {
                    top[2] = top[1];
                    top[1] = top[0];
                    top[0] = a;
                } else if (a > top[1]) {
                    top[2] = top[1];
                    top[1] = a;
                } else if (a > top[2]) {
                    top[2] = a;
                }
            }
            // fewer than three increments: the smallest there is
            c.scale = n_inc >= 3 ? top[2] : n_inc == 2 ? top[1] : top[0];
            std::size_t i0 = 0;
            while (i0 < n_queued && !std::isfinite(row(i0)[k])) ++i0;
            if (i0 + 2 >= n_queued) continue;
            const double x0 = row(i0)[k], x1 = row(i0 + 1)[k], x2 = row(i0 + 2)[k];
            if (!std::isfinite(x1) || !std::isfinite(x2)) continue;
            Channel probe = c;
            probe.ref = x1;  // the floor's relative part at the neighbours' level
            if (std::fabs(x1 - x0) > K * std::max({c.scale, floor_of(probe), std::fabs(x2 - x1)})) {
                take_out(i0, k);
                count(1);
            }
        }
    }

    // Decides what can be decided (at_end: with the successors there are).
    void decide(bool at_end) {
        if (!warm) {
            if (!at_end && n_queued < warmup) return;
            end_warmup();
        }
        while (n_decided < n_queued) {
            const std::size_t i = n_decided;
            // a sample is tested once: when it becomes the oldest undecided one (a sample
            // that waits was tested when it came first)
            const bool waiting = suspect_waits || test(i);
            suspect_waits = waiting;
            if (waiting) {
                if (!at_end && !can_resolve(i)) return;  // waits for its successors
                resolve(i);
                suspect_waits = false;
            }
            ++n_decided;
        }
    }

    // Drops what the last call released: the waiting samples move to the front.
    void drop_released() {
        if (!n_released) return;
        const std::size_t keep = n_queued - n_released;
        std::memmove(vals.data(), row(n_released), keep * n * sizeof(double));
        std::memmove(out.data(), mark(n_released), keep * n);
        n_queued = keep;
        n_decided -= n_released;
        n_released = 0;
    }

    void reset() {
        std::fill(ch.begin(), ch.end(), Channel{});
        n_queued = n_decided = n_released = 0;
        warm = suspect_waits = false;
        stats = vibid_outlier_stats{};
    }
};

VIBID_API void vibid_outlier_config_init(vibid_outlier_config *cfg, size_t n_channels) {
    if (!cfg) return;
    std::memset(cfg, 0, sizeof *cfg);
    cfg->n_channels = n_channels;
    cfg->threshold = VIBID_OUTLIER_THRESHOLD_DEFAULT;
    cfg->memory = VIBID_OUTLIER_MEMORY_DEFAULT;
    cfg->warmup = VIBID_OUTLIER_WARMUP_DEFAULT;
}

VIBID_API vibid_outlier *vibid_outlier_create(const vibid_outlier_config *cfg) {
    return vibid::guard_create<vibid_outlier>(__func__, [&]() -> vibid_outlier * {
        using vibid::throw_error;
        if (!cfg) throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
        if (cfg->n_channels < 1 || cfg->n_channels > (1u << 20))
            throw_error(VIBID_E_DIMENSION, "n_channels = %zu outside [1, 1048576]", cfg->n_channels);
        if (!(cfg->threshold >= 2.0) || !std::isfinite(cfg->threshold))
            throw_error(VIBID_E_OUT_OF_RANGE, "threshold = %g must be finite and >= 2", cfg->threshold);
        if (!(cfg->memory >= 1.0) || !std::isfinite(cfg->memory))
            throw_error(VIBID_E_OUT_OF_RANGE, "memory = %g samples must be finite and >= 1", cfg->memory);
        if (cfg->warmup < 4 || cfg->warmup > VIBID_OUTLIER_MAX_WARMUP)
            throw_error(VIBID_E_OUT_OF_RANGE, "warmup = %zu outside [4, %d]", cfg->warmup, VIBID_OUTLIER_MAX_WARMUP);
        auto *d = new vibid_outlier;
        d->n = cfg->n_channels;
        d->K = cfg->threshold;
        d->decay = std::exp(-1.0 / cfg->memory);
        d->warmup = cfg->warmup;
        d->cap = std::max(cfg->warmup, kLookahead + 1) + 1;
        try {
            d->ch.assign(d->n, Channel{});
            d->vals.assign(d->cap * d->n, 0.0);
            d->out.assign(d->cap * d->n, 0);
        } catch (...) {
            delete d;
            throw;
        }
        return d;
    });
}

VIBID_API vibid_status vibid_outlier_reset(vibid_outlier *det) {
    if (!det) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det is NULL");
    det->reset();
    return VIBID_OK;
}

VIBID_API void vibid_outlier_destroy(vibid_outlier *det) { delete det; }

VIBID_API vibid_status vibid_outlier_push(vibid_outlier *det, const double *values, size_t *n_released) {
    if (!det || !values || !n_released)
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det, values and n_released are required");
    det->drop_released();
    // cannot overflow: at most warmup samples wait before the warm-up ends, a suspect and
    // its kLookahead successors after it
    const std::size_t i = det->n_queued++;
    std::memcpy(det->row(i), values, det->n * sizeof(double));
    std::memset(det->mark(i), 0, det->n);
    ++det->stats.samples;
    det->decide(false);
    *n_released = det->n_released = det->n_decided;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_outlier_flush(vibid_outlier *det, size_t *n_released) {
    if (!det || !n_released) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det and n_released are required");
    det->drop_released();
    det->decide(true);
    *n_released = det->n_released = det->n_decided;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_outlier_released(const vibid_outlier *det, size_t i, double *values_out,
                                              unsigned char *outlier_out, size_t *n_outliers) {
    if (!det) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det is NULL");
    if (i >= det->n_released)
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "i = %zu: the last call released %zu samples", i, det->n_released);
    if (values_out) std::memcpy(values_out, det->row(i), det->n * sizeof(double));
    const unsigned char *m = det->out.data() + i * det->n;
    if (outlier_out) std::memcpy(outlier_out, m, det->n);
    if (n_outliers) {
        std::size_t t = 0;
        for (std::size_t k = 0; k < det->n; ++k) t += m[k];
        *n_outliers = t;
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_outlier_get_stats(const vibid_outlier *det, vibid_outlier_stats *stats) {
    if (!det || !stats) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det and stats are required");
    *stats = det->stats;
    return VIBID_OK;
}
