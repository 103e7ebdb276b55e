// vibid._core, the parts over the drivers and vibidd's core (issue 13); compiled in only when
// the build found them (python/CMakeLists.txt defines VIBID_HAVE_DRIVERS, VIBID_HAVE_DAEMON).
//
//  read_candump: a candump log decoded through the DBC and the CAN sample assembler by the
//    drivers' replay source, the very code `vibidd --replay` runs, so the samples are the
//    daemon's bit for bit. Nothing is decoded here.
//  replay_run: vibidd's pipeline (config reader, replay source, estimator, writers) run
//    in-process through vd_daemon_init / vd_daemon_run, the functions vibidd's main() calls,
//    with the tracks written to a file the caller names.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

extern "C" {
#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/sample.h>
#include <vibid_drivers/source.h>
#include <vibid_drivers/source_replay.h>
}
#ifdef VIBID_HAVE_DAEMON
#include "vibid_replay.h"  // the daemon's C11 headers stay in vibid_replay.c
#endif

#include <locale.h>
#include <pthread.h>
#include <signal.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
#include <vector>

namespace nb = nanobind;
using namespace nb::literals;

namespace {

// The DBC and CSV parsers read numbers with strtod, which follows LC_NUMERIC (dbc.h). Python
// leaves it "C" unless a program calls locale.setlocale(LC_ALL, ""); then "1,5" locales
// would misread every factor, so refuse instead of decoding wrong values.
void require_c_numeric(const char *what) {
    const struct lconv *lc = localeconv();
    if (!lc || std::strcmp(lc->decimal_point, ".") != 0)
        throw nb::value_error((std::string(what) + ": the numeric locale's decimal point is '" +
                               (lc ? lc->decimal_point : "?") +
                               "', the DBC and capture parsers need '.': call locale.setlocale(locale.LC_NUMERIC, "
                               "'C') first")
                                  .c_str());
}

void copy_name(char *dst, size_t cap, const std::string &s, const char *what) {
    if (s.size() >= cap)
        throw nb::value_error((std::string(what) + " '" + s + "': longer than " + std::to_string(cap - 1) +
                               " characters")
                                  .c_str());
    std::memcpy(dst, s.c_str(), s.size() + 1);
}

struct DbcDel {
    void operator()(vibid_dbc *d) const noexcept { vibid_dbc_destroy(d); }
};
struct SourceDel {
    void operator()(vibid_source *s) const noexcept { vibid_source_close(s); }
};

// The stand's channels as listed in a channel-map file (docs/drivers.md): *map is the file's
// map, col[i] the map's index of stand channel i. Raises when the file lacks one.
void chanmap_from_file(const std::string &chanmap_path, const std::vector<std::string> &channels, vibid_chanmap *map,
                       std::vector<size_t> &col) {
    vibid_cfg_error ce{};
    if (vibid_chanmap_read_file(chanmap_path.c_str(), map, &ce) != VIBID_DRV_OK) throw nb::value_error(ce.text);
    for (size_t i = 0; i < channels.size(); ++i) {
        size_t k = 0;
        while (k < map->n && channels[i] != map->ch[k].name) ++k;
        if (k == map->n)
            throw nb::value_error((chanmap_path + ": no channel '" + channels[i] +
                                   "', which the stand reads (a channel-map entry with name = \"" + channels[i] +
                                   "\" and the DBC signal that carries it)")
                                      .c_str());
        col[i] = k;
    }
}

// "M1.a, M1.b, M2.c": every signal of the DBC, for the message that names one missing.
std::string dbc_signal_list(const vibid_dbc *dbc) {
    std::string have;
    for (size_t m = 0; m < vibid_dbc_message_count(dbc); ++m) {
        const vibid_dbc_message *mm = vibid_dbc_message_at(dbc, m);
        for (size_t s = 0; s < mm->n_signals; ++s)
            have += std::string(have.empty() ? "" : ", ") + mm->name + "." + mm->signals[s].name;
    }
    return have;
}

// The default map: stand channel i is the DBC signal signals[i] (its own name unless
// renamed), found in any message, in exactly one. The quantity and node fields are vibidd's
// check against the stand; the assembler reads only the signal, so they stay zero here.
// Apart from reading: it decides how samples are assembled (the counter), before any frame.
void chanmap_from_dbc(const vibid_dbc *dbc, const std::string &dbc_path, const std::vector<std::string> &channels,
                      const std::vector<std::string> &signals, vibid_chanmap *map, std::vector<size_t> &col) {
    map->n = channels.size();
    const vibid_dbc_message *first_msg = nullptr;
    bool one_message = true, all_have_counter = true;
    for (size_t i = 0; i < channels.size(); ++i) {
        vibid_channel &ch = map->ch[i];
        copy_name(ch.name, sizeof ch.name, channels[i], "channel");
        copy_name(ch.ref, sizeof ch.ref, signals[i], "signal");
        ch.source = VIBID_CHAN_SIGNAL;
        ch.node = -1;
        const vibid_dbc_message *msg = nullptr, *second = nullptr;
        const vibid_dbc_signal *sig = vibid_dbc_lookup_signal(dbc, ch.ref, nullptr, &msg, &second);
        std::string called = "'" + signals[i] + "'" +
                             (signals[i] == channels[i] ? "" : " (the stand's channel '" + channels[i] + "')");
        if (second)
            throw nb::value_error((dbc_path + ": signal " + called + " is in messages " + msg->name + " and " +
                                   second->name + ": give a channel map naming the message")
                                      .c_str());
        if (!sig) {
            std::string have = dbc_signal_list(dbc);
            throw nb::value_error((dbc_path + " has no signal " + called + " (its signals: " +
                                   (have.empty() ? "none" : have) +
                                   "); rename with channels={stand channel: signal} or give a channel map")
                                      .c_str());
        }
        if (first_msg && msg != first_msg) one_message = false;
        if (!first_msg) first_msg = msg;
        if (!vibid_dbc_find_signal(msg, "SampleCounter")) all_have_counter = false;
        col[i] = i;
    }
    // vibid-sim numbers every frame with SampleCounter (docs/sim.md), as vibidd's
    // maps for its logs say (counter = "SampleCounter"). Without a counter in every
    // message the samples can only be assembled from a single message.
    if (all_have_counter)
        std::strcpy(map->counter, "SampleCounter");
    else if (!one_message)
        throw nb::value_error((dbc_path + ": the stand's channels come from several messages and not all of "
                                          "them carry a SampleCounter signal: give a channel map with counter = "
                                          "\"<signal>\" or trigger = \"<message>\" (docs/drivers.md)")
                                  .c_str());
}

// What the replay source delivered: per stand channel its values, per row the time and
// whether it is a sample or a row of a gap; the gaps and faults as records; the source's
// counters; a fatal error's text ("" when none).
struct CandumpRows {
    std::vector<std::vector<double>> values;  // [channel][row]
    std::vector<int64_t> t_ns;
    std::vector<uint8_t> present;  // 1: a sample, 0: a row of a gap
    std::vector<uint64_t> gap_row, gap_count;
    std::vector<std::string> gap_text, fault_kind, fault_text;
    vibid_source_stats stats{};
    std::string fatal;
};

// One record into rows: a fault is listed, a sample appended, a gap appended as NaN rows
// (missing samples stay missing: rows the identify check refuses). first: the index of the
// first sample or gap, from which gap rows count.
void append_record(const vibid_record &rec, const std::vector<size_t> &col, bool &started, uint64_t &first,
                   CandumpRows &rows) {
    const size_t nch = col.size();
    if (rec.kind == VIBID_REC_FAULT) {
        rows.fault_kind.emplace_back(vibid_fault_name(rec.fault));
        rows.fault_text.emplace_back(rec.text);
        return;
    }
    if (!started) {
        started = true;
        first = rec.index;
    }
    if (rec.kind == VIBID_REC_SAMPLE) {
        for (size_t c = 0; c < nch; ++c) rows.values[c].push_back(rec.values[col[c]]);
        rows.t_ns.push_back(rec.t_ns);
        rows.present.push_back(1);
        return;
    }
    rows.gap_row.push_back(rec.index - first);
    rows.gap_count.push_back(rec.count);
    rows.gap_text.emplace_back(rec.text);
    for (uint64_t k = 0; k < rec.count; ++k) {
        for (size_t c = 0; c < nch; ++c) rows.values[c].push_back(NAN);
        rows.t_ns.push_back(0);
        rows.present.push_back(0);
    }
}

// Every record of the capture through the drivers' replay source (the code vibidd --replay
// runs). Pure C work, run by the caller without the GIL: it may take seconds.
void read_replay_records(const vibid_source_replay_config &rc, const std::string &path, const std::vector<size_t> &col,
                         CandumpRows &rows) {
    vibid_drv_error de{};
    rows.values.resize(col.size());
    std::unique_ptr<vibid_source, SourceDel> src(vibid_source_open(&vibid_source_replay_ops, &rc, &de));
    if (!src) {
        rows.fatal = de.text;
        return;
    }
    std::vector<vibid_record> recs(64);
    bool started = false;
    uint64_t first = 0;
    for (;;) {
        size_t n = 0;
        vibid_drv_status s = vibid_source_read(src.get(), recs.data(), recs.size(), &n, -1, &de);
        if (s == VIBID_DRV_E_EOF) break;
        if (s != VIBID_DRV_OK && s != VIBID_DRV_E_AGAIN) {
            rows.fatal = path + ": " + de.text;
            break;
        }
        for (size_t r = 0; r < n; ++r) append_record(recs[r], col, started, first, rows);
    }
    vibid_source_stats_get(src.get(), &rows.stats);
}

// Units: the channel map's, else the DBC signal's (docs/drivers.md); "" = the stand's.
std::vector<std::string> channel_units(const vibid_dbc *dbc, const vibid_chanmap &map, const std::vector<size_t> &col) {
    std::vector<std::string> units(col.size());
    for (size_t i = 0; i < col.size(); ++i) {
        const vibid_channel &ch = map.ch[col[i]];
        if (ch.unit[0]) {
            units[i] = ch.unit;
            continue;
        }
        const vibid_dbc_message *msg = nullptr, *second = nullptr;
        const vibid_dbc_signal *sig = vibid_dbc_lookup_signal(dbc, ch.ref, ch.message, &msg, &second);
        if (sig && sig->unit) units[i] = sig->unit;
    }
    return units;
}

// Time: seconds from the first sample, from the integer nanoseconds (exact); NaN in gaps.
// *t0: the first sample's time in ns (0 when there is none).
std::vector<double> seconds_from_first_sample(const CandumpRows &rows, int64_t *t0) {
    const size_t n = rows.present.size();
    std::vector<double> t(n, NAN);
    *t0 = 0;
    for (size_t k = 0; k < n; ++k)
        if (rows.present[k]) {
            *t0 = rows.t_ns[k];
            break;
        }
    for (size_t k = 0; k < n; ++k)
        if (rows.present[k]) t[k] = static_cast<double>(rows.t_ns[k] - *t0) * 1e-9;
    return t;
}

// A numpy array that owns v's buffer (no copy): the one way columns and time leave here.
nb::object numpy_owning(std::vector<double> &&v) {
    auto *heap = new std::vector<double>(std::move(v));
    nb::capsule owner(heap, [](void *p) noexcept { delete static_cast<std::vector<double> *>(p); });
    return nb::ndarray<nb::numpy, double, nb::ndim<1>>(heap->data(), {heap->size()}, owner).cast();
}

// The result read_candump documents (vibid/_captures.py reads it): columns, time, units,
// gaps, faults, the counter or trigger used, the source's counters.
nb::dict candump_result(CandumpRows &rows, const vibid_chanmap &map, std::vector<std::string> &&units) {
    int64_t t0;
    std::vector<double> t = seconds_from_first_sample(rows, &t0);
    nb::dict out;
    nb::list cols;
    for (auto &v : rows.values) cols.append(numpy_owning(std::move(v)));
    out["values"] = cols;
    out["time_s"] = numpy_owning(std::move(t));
    out["start_time_ns"] = t0;
    out["units"] = units;
    nb::list gaps;
    for (size_t g = 0; g < rows.gap_row.size(); ++g) {
        nb::dict d;
        d["row"] = rows.gap_row[g];
        d["count"] = rows.gap_count[g];
        d["text"] = rows.gap_text[g];
        gaps.append(d);
    }
    out["gaps"] = gaps;
    nb::list faults;
    for (size_t f = 0; f < rows.fault_kind.size(); ++f) {
        nb::dict d;
        d["kind"] = rows.fault_kind[f];
        d["text"] = rows.fault_text[f];
        faults.append(d);
    }
    out["faults"] = faults;
    out["counter"] = std::string(map.counter);
    out["trigger"] = std::string(map.trigger);
    const vibid_source_stats &st = rows.stats;
    nb::dict stats;
    stats["lines"] = st.lines;
    stats["frames"] = st.frames;
    stats["bad_lines"] = st.bad_lines;
    stats["dropped"] = st.dropped;
    stats["samples"] = st.samples;
    stats["gaps"] = st.gaps;
    stats["missing_samples"] = st.missing_samples;
    stats["faults"] = st.faults;
    out["stats"] = stats;
    return out;
}

// A candump log through the drivers' replay source. channels: the stand's channel names;
// signals: the DBC signal read for each (the same names unless renamed); chanmap_path: a
// channel-map file (docs/drivers.md) instead, whose channels must include the stand's.
nb::dict read_candump(const std::string &path, const std::string &dbc_path, const std::vector<std::string> &channels,
                      const std::vector<std::string> &signals, const std::optional<std::string> &chanmap_path,
                      double sample_rate) {
    require_c_numeric(path.c_str());
    if (channels.size() != signals.size() || channels.empty() || channels.size() > VIBID_DRV_MAX_CHANNELS)
        throw nb::value_error("read_candump: channels and signals must be 1..32 names each, as many of both");
    vibid_drv_error de{};
    std::unique_ptr<vibid_dbc, DbcDel> dbc(vibid_dbc_load(dbc_path.c_str(), &de));
    if (!dbc) throw nb::value_error(de.text);

    auto map = std::make_unique<vibid_chanmap>();
    std::memset(map.get(), 0, sizeof *map);
    std::vector<size_t> col(channels.size());  // stand channel i -> channel-map index
    if (chanmap_path)
        chanmap_from_file(*chanmap_path, channels, map.get(), col);
    else
        chanmap_from_dbc(dbc.get(), dbc_path, channels, signals, map.get(), col);

    vibid_source_replay_config rc{};
    rc.path = path.c_str();
    rc.format = VIBID_REPLAY_CANDUMP;
    rc.dbc = dbc.get();
    rc.chanmap = *map;
    rc.paced = false;
    rc.speed = 1.0;
    // the assembler's counter plausibility check (can_assembler.h), as vibidd sets it
    rc.sample_period_s = sample_rate > 0 ? 1.0 / sample_rate : 0.0;

    CandumpRows rows;
    {
        nb::gil_scoped_release release;
        read_replay_records(rc, path, col, rows);
    }
    if (!rows.fatal.empty()) throw nb::value_error(rows.fatal.c_str());
    return candump_result(rows, *map, channel_units(dbc.get(), *map, col));
}

#ifdef VIBID_HAVE_DAEMON
struct ReplayDel {
    void operator()(vibid_py_replay *r) const noexcept { vibid_py_replay_close(r); }
};

// vibidd -c config [--replay capture] with its outputs replaced by the tracks file
// tracks_path, run by the daemon's own code (vibid_replay.c). Returns vibidd's exit status
// of the run (0 ok; 1 a run-time failure, which the daemon has logged on stderr); raises
// ValueError with the daemon's message for what it refuses before running (the
// configuration's file:line: field: reason, a capture whose rate does not fit, ...).
int replay_run(const std::string &config, const std::optional<std::string> &capture, const std::string &tracks_path,
               const std::string &log_level, const std::string &rate_check) {
    require_c_numeric(config.c_str());
    int level = vibid_py_log_level_parse(log_level.c_str());
    if (level < 0)
        throw nb::value_error(("log_level '" + log_level + "': error, warning, notice, info or debug").c_str());
    int rmode = vibid_py_rate_mode_parse(rate_check.c_str());
    if (rmode < 0) throw nb::value_error(("rate_check '" + rate_check + "': error, warn or off").c_str());

    std::string err_text;
    int rc = 0;
    bool interrupted = false;
    {
        nb::gil_scoped_release release;
        int old_level = vibid_py_log_level_set(level);
        std::vector<char> err(8192);
        std::unique_ptr<vibid_py_replay, ReplayDel> r(vibid_py_replay_open(
            config.c_str(), capture ? capture->c_str() : nullptr, tracks_path.c_str(), rmode, err.data(), err.size()));
        if (!r) {
            err_text = err.data();
        } else {
            // vd_daemon_run blocks SIGTERM, SIGINT, SIGHUP and SIGUSR1 in its thread and waits
            // for them with sigtimedwait. On a thread of its own, with every signal blocked
            // from its start, it takes none of them from the interpreter: Ctrl-C still
            // reaches Python's handler, which this thread polls, and the pipeline is stopped
            // the daemon's way (SIGTERM to its thread: drain, flush, exit).
            struct Ctx {
                vibid_py_replay *r;
                int rc;
                std::atomic<bool> done;
            } ctx{r.get(), 0, {false}};
            auto body = [](void *p) -> void * {
                auto *c = static_cast<Ctx *>(p);
                c->rc = vibid_py_replay_run(c->r);
                c->done.store(true);
                return nullptr;
            };
            sigset_t all, old;
            sigfillset(&all);
            pthread_sigmask(SIG_BLOCK, &all, &old);
            pthread_t th{};
            int ce = pthread_create(&th, nullptr, body, &ctx);
            pthread_sigmask(SIG_SETMASK, &old, nullptr);
            if (ce != 0) {
                err_text = std::string("cannot start the pipeline's thread: ") + std::strerror(ce);
            } else {
                while (!ctx.done.load()) {
                    std::this_thread::sleep_for(std::chrono::milliseconds(20));
                    nb::gil_scoped_acquire acquire;
                    if (PyErr_CheckSignals() != 0) {
                        interrupted = true;
                        pthread_kill(th, SIGTERM);
                        break;
                    }
                }
                pthread_join(th, nullptr);
                rc = ctx.rc;
            }
        }
        r.reset();
        vibid_py_log_level_set(old_level);
    }
    if (interrupted) throw nb::python_error();
    if (!err_text.empty()) throw nb::value_error(err_text.c_str());
    return rc;
}
#endif

}  // namespace

void vibid_register_drivers(nb::module_ &m) {
    m.def("read_candump", &read_candump, "path"_a, "dbc"_a, "channels"_a, "signals"_a, "chanmap"_a.none(),
          "sample_rate"_a);
#ifdef VIBID_HAVE_DAEMON
    m.def("replay_run", &replay_run, "config"_a, "capture"_a.none(), "tracks"_a, "log_level"_a, "rate_check"_a);
#endif
}
