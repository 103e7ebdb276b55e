// vibid._core, the parts over the drivers and vibidd's core (issue 13); compiled in only when
// the build found them (python/CMakeLists.txt defines VIBID_HAVE_DRIVERS, VIBID_HAVE_DAEMON).
//
//  read_candump: a candump log decoded through the DBC and the CAN sample assembler by the
//    drivers' replay source, the very code `vibidd --replay` runs, so the samples are the
//    daemon's bit for bit. Nothing is decoded here.
//  candump_plan, write_candump: samples written as a candump log by the drivers' CAN
//    encoder (vibid_can_assembler_encode, what vibidd's candump recording uses), the inverse
//    of read_candump through the same channel map; nothing is encoded here.
//  replay_run: vibidd's pipeline (config reader, replay source, estimator, writers) run
//    in-process through vd_daemon_init / vd_daemon_run, the functions vibidd's main() calls,
//    with the tracks written to a file the caller names.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

extern "C" {
#include <vibid_drivers/can_assembler.h>
#include <vibid_drivers/candump.h>
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
#include <cerrno>
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
// hint: what to do about a missing signal, for the message (read_capture's keywords, or the
// command line's options).
void chanmap_from_dbc(const vibid_dbc *dbc, const std::string &dbc_path, const std::vector<std::string> &channels,
                      const std::vector<std::string> &signals, vibid_chanmap *map, std::vector<size_t> &col,
                      const char *hint = "rename with channels={stand channel: signal} or give a channel map") {
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
                                   (have.empty() ? "none" : have) + "); " + hint)
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

// ---- writing: samples as a candump log (vibid convert --to candump) ----

struct AssemblerDel {
    void operator()(vibid_can_assembler *a) const noexcept { vibid_can_assembler_destroy(a); }
};

// What a candump log of the stand's channels is written with: the DBC, the channel map of
// the stand's channels alone in the stand's order (a channel-map file's other channels carry
// nothing the capture holds: their signals are not written), each channel's message and
// signal, and the drivers' assembler, whose encoder writes the frames (the inverse of the
// reader through the same map: can_assembler.h).
struct Encoding {
    std::unique_ptr<vibid_dbc, DbcDel> dbc;
    std::unique_ptr<vibid_chanmap> map;
    std::vector<const vibid_dbc_message *> msg;
    std::vector<const vibid_dbc_signal *> sig;
    std::vector<std::string> unit;  // the channel map's, else the signal's
    unsigned counter_bits = 0;      // counter mode: the counter signal's bits
    std::unique_ptr<vibid_can_assembler, AssemblerDel> enc;
};

std::unique_ptr<Encoding> encoding(const std::string &dbc_path, const std::vector<std::string> &channels,
                                   const std::vector<std::string> &signals, const std::optional<std::string> &chanmap_path,
                                   const std::string &hint) {
    require_c_numeric(dbc_path.c_str());
    if (channels.size() != signals.size() || channels.empty() || channels.size() > VIBID_DRV_MAX_CHANNELS)
        throw nb::value_error("write_candump: channels and signals must be 1..32 names each, as many of both");
    auto e = std::make_unique<Encoding>();
    vibid_drv_error de{};
    e->dbc.reset(vibid_dbc_load(dbc_path.c_str(), &de));
    if (!e->dbc) throw nb::value_error(de.text);
    e->map = std::make_unique<vibid_chanmap>();
    std::memset(e->map.get(), 0, sizeof *e->map);
    std::vector<size_t> col(channels.size());
    if (chanmap_path) {
        auto file = std::make_unique<vibid_chanmap>();
        std::memset(file.get(), 0, sizeof *file);
        chanmap_from_file(*chanmap_path, channels, file.get(), col);
        e->map->n = channels.size();
        for (size_t i = 0; i < channels.size(); ++i) e->map->ch[i] = file->ch[col[i]];
        std::memcpy(e->map->counter, file->counter, sizeof file->counter);
        std::memcpy(e->map->trigger, file->trigger, sizeof file->trigger);
    } else {
        chanmap_from_dbc(e->dbc.get(), dbc_path, channels, signals, e->map.get(), col, hint.c_str());
    }
    e->enc.reset(vibid_can_assembler_create(e->dbc.get(), e->map.get(), &de));
    if (!e->enc)
        throw nb::value_error(((chanmap_path ? *chanmap_path + " with " : std::string()) + dbc_path + ": " + de.text)
                                  .c_str());
    for (size_t i = 0; i < channels.size(); ++i) {
        const vibid_channel &ch = e->map->ch[i];
        const vibid_dbc_message *m = nullptr, *second = nullptr;
        const vibid_dbc_signal *s = vibid_dbc_lookup_signal(e->dbc.get(), ch.ref, ch.message, &m, &second);
        e->msg.push_back(m);  // found: the assembler was created with the same lookup
        e->sig.push_back(s);
        e->unit.emplace_back(ch.unit[0] ? ch.unit : (s->unit ? s->unit : ""));
    }
    if (e->map->counter[0]) {
        e->counter_bits = vibid_dbc_find_signal(e->msg[0], e->map->counter)->length;
    } else if (e->map->trigger[0]) {
        // The encoder writes the messages that hold channels; a trigger message that holds
        // none would have to be written with nothing in it, and without it a reader
        // assembles no sample at all.
        const vibid_dbc_message *t = vibid_dbc_find_message_by_name(e->dbc.get(), e->map->trigger);
        bool carries = false;
        for (const vibid_dbc_message *m : e->msg) carries = carries || m == t;
        if (!carries)
            throw nb::value_error((*chanmap_path + ": trigger message " + e->map->trigger +
                                   " carries none of the stand's channels: a log written without its frames "
                                   "would hold no sample; give a counter signal or a trigger message that holds a "
                                   "channel")
                                      .c_str());
    }
    return e;
}

const char *value_type_name(vibid_dbc_value_type t) {
    return t == VIBID_DBC_FLOAT32 ? "float32" : t == VIBID_DBC_FLOAT64 ? "float64" : "integer";
}

// How the stand's channels would be written: per channel its message, signal and the
// signal's encoding (for the caller's checks and messages); the counter or trigger.
nb::dict candump_plan(const std::string &dbc_path, const std::vector<std::string> &channels,
                      const std::vector<std::string> &signals, const std::optional<std::string> &chanmap_path,
                      const std::string &hint) {
    auto e = encoding(dbc_path, channels, signals, chanmap_path, hint);
    nb::list chans;
    for (size_t i = 0; i < channels.size(); ++i) {
        const vibid_dbc_signal *s = e->sig[i];
        nb::dict d;
        d["message"] = std::string(e->msg[i]->name);
        d["signal"] = std::string(s->name);
        d["unit"] = e->unit[i];
        d["factor"] = s->factor;
        d["offset"] = s->offset;
        d["minimum"] = s->minimum;
        d["maximum"] = s->maximum;
        d["length"] = static_cast<unsigned>(s->length);
        d["signed"] = s->is_signed;
        d["type"] = std::string(value_type_name(s->value_type));
        chans.append(d);
    }
    nb::dict out;
    out["channels"] = chans;
    out["counter"] = std::string(e->map->counter);
    out["counter_bits"] = e->counter_bits;
    out["trigger"] = std::string(e->map->trigger);
    out["messages"] = vibid_can_assembler_ids(e->enc.get(), nullptr, 0);
    return out;
}

struct FileDel {
    void operator()(FILE *f) const noexcept { std::fclose(f); }
};

// Writes the samples (values[row][channel] in the signals' units, rows in time order; their
// sample indices, which number the counter, and times in microseconds) as a candump -l log
// at out_path: the frames vibid_can_assembler_encode makes of each sample, formatted by
// vibid_candump_format, all at the sample's time (as vibidd's candump recording). Per
// channel, how many values the frames hold other than given (rounded to the signal's step
// by more than 1e-9 of it, or to float32) and by how much at most, from decoding each
// written signal. A value that
// does not fit its signal stops the writing: failed_row (of the arrays), failed_channel and
// the encoder's text.
nb::dict write_candump(const std::string &out_path, const std::string &dbc_path, const std::vector<std::string> &channels,
                       const std::vector<std::string> &signals, const std::optional<std::string> &chanmap_path,
                       const std::string &hint,
                       nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> values,
                       nb::ndarray<const uint64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu> index,
                       nb::ndarray<const int64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu> t_us,
                       const std::string &iface) {
    auto e = encoding(dbc_path, channels, signals, chanmap_path, hint);
    const size_t nch = channels.size(), rows = values.shape(0);
    if (values.shape(1) != nch || index.shape(0) != rows || t_us.shape(0) != rows)
        throw nb::value_error("write_candump: values must be rows x channels, index and t_us one per row");
    if (iface.empty() || iface.size() >= VIBID_CAN_IFNAMSIZ || iface.find_first_of(" \t\r\n()#") != std::string::npos)
        throw nb::value_error(("interface name '" + iface + "': 1.." + std::to_string(VIBID_CAN_IFNAMSIZ - 1) +
                               " characters, no blanks, parentheses or '#'")
                                  .c_str());
    std::unique_ptr<FILE, FileDel> f(std::fopen(out_path.c_str(), "w"));
    if (!f) {
        PyErr_SetFromErrnoWithFilename(PyExc_OSError, out_path.c_str());
        throw nb::python_error();
    }
    std::vector<uint64_t> rounded(nch, 0);
    std::vector<double> max_err(nch, 0.0);
    uint64_t frames = 0;
    int64_t fail_row = -1, fail_channel = -1;
    std::string fail_text;
    bool io_error = false;
    int io_errno = 0;
    {
        nb::gil_scoped_release release;
        const double *v = values.data();
        std::vector<vibid_can_frame> fr(vibid_can_assembler_ids(e->enc.get(), nullptr, 0) + 1);
        std::vector<char> line(256);
        std::vector<double> tol(nch, 0.0);
        for (size_t c = 0; c < nch; ++c)
            if (e->sig[c]->value_type == VIBID_DBC_INTEGER) tol[c] = 1e-9 * std::fabs(e->sig[c]->factor);
        vibid_record rec{};
        rec.kind = VIBID_REC_SAMPLE;
        rec.n_values = static_cast<uint32_t>(nch);
        for (size_t r = 0; r < rows && fail_row < 0 && !io_error; ++r) {
            rec.index = index.data()[r];
            rec.t_ns = t_us.data()[r] * 1000;
            for (size_t c = 0; c < nch; ++c) rec.values[c] = v[r * nch + c];
            size_t n = 0;
            vibid_drv_error de{};
            if (vibid_can_assembler_encode(e->enc.get(), &rec, fr.data(), fr.size(), &n, &de) != VIBID_DRV_OK) {
                fail_row = static_cast<int64_t>(r);
                fail_text = de.text;
                // the channel: the first whose value its signal refuses on its own
                uint8_t scratch[VIBID_CANFD_MAX_DLEN] = {0};
                for (size_t c = 0; c < nch && fail_channel < 0; ++c)
                    if (vibid_dbc_signal_encode(e->sig[c], rec.values[c], scratch, sizeof scratch) != VIBID_DRV_OK)
                        fail_channel = static_cast<int64_t>(c);
                break;
            }
            for (size_t c = 0; c < nch; ++c) {
                // the value as a reader decodes it from the frame written
                for (size_t k = 0; k < n; ++k) {
                    if (fr[k].id != e->msg[c]->id || ((fr[k].flags & VIBID_CAN_F_EXT) != 0) != e->msg[c]->extended)
                        continue;
                    double back = NAN;
                    vibid_dbc_signal_decode(e->sig[c], fr[k].data, fr[k].len, &back);
                    // Rounded: moved by more than a billionth of the step (an integer signal; less is
                    // the double arithmetic of raw * factor + offset on a value that lies on the
                    // grid), or at all (a float signal: float32's rounding).
                    double d = std::fabs(back - rec.values[c]);
                    if (!(d <= tol[c])) {
                        ++rounded[c];
                        if (!(d <= max_err[c])) max_err[c] = d;  // NaN (a float NaN sent) kept
                    }
                    break;
                }
            }
            for (size_t k = 0; k < n; ++k) {
                int len = vibid_candump_format(line.data(), line.size(), &fr[k], iface.c_str());
                if (len < 0 || std::fprintf(f.get(), "%s\n", line.data()) < 0) {
                    io_errno = len < 0 ? EINVAL : errno;
                    io_error = true;
                    break;
                }
                ++frames;
            }
        }
        if (!io_error && std::fflush(f.get()) != 0) {
            io_errno = errno;
            io_error = true;
        }
    }
    if (std::fclose(f.release()) != 0 && !io_error) {
        io_errno = errno;
        io_error = true;
    }
    if (io_error) {
        errno = io_errno;
        PyErr_SetFromErrnoWithFilename(PyExc_OSError, out_path.c_str());
        throw nb::python_error();
    }
    nb::dict out;
    out["frames"] = frames;
    out["rounded"] = rounded;
    out["max_error"] = max_err;
    out["failed_row"] = fail_row;
    out["failed_channel"] = fail_channel;
    out["failed_text"] = fail_text;
    return out;
}

#ifdef VIBID_HAVE_DAEMON
struct ReplayDel {
    void operator()(vibid_py_replay *r) const noexcept { vibid_py_replay_close(r); }
};

// vibidd -c config [--replay capture] with its outputs replaced by the tracks file
// tracks_path (and the InfluxDB line file influx_path when given; reference: the alarms'
// reference file in place of the configuration's, "" none), run by the daemon's own code
// (vibid_replay.c). Returns vibidd's exit status
// of the run (0 ok; 1 a run-time failure, which the daemon has logged on stderr); raises
// ValueError with the daemon's message for what it refuses before running (the
// configuration's file:line: field: reason, a capture whose rate does not fit, ...).
int replay_run(const std::string &config, const std::optional<std::string> &capture, const std::string &tracks_path,
               const std::string &log_level, const std::string &rate_check,
               const std::optional<std::string> &influx_path, const std::optional<std::string> &reference) {
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
            config.c_str(), capture ? capture->c_str() : nullptr, tracks_path.c_str(),
            influx_path ? influx_path->c_str() : nullptr, reference ? reference->c_str() : nullptr, rmode, err.data(),
            err.size()));
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
    m.def("candump_plan", &candump_plan, "dbc"_a, "channels"_a, "signals"_a, "chanmap"_a.none(), "hint"_a);
    m.def("write_candump", &write_candump, "path"_a, "dbc"_a, "channels"_a, "signals"_a, "chanmap"_a.none(),
          "hint"_a, "values"_a, "index"_a, "t_us"_a, "iface"_a);
#ifdef VIBID_HAVE_DAEMON
    m.def("replay_run", &replay_run, "config"_a, "capture"_a.none(), "tracks"_a, "log_level"_a, "rate_check"_a,
          "influx"_a.none() = nb::none(), "reference"_a.none() = nb::none());
#endif
}
