/* sim/sim_faults.c: see sim_faults.h. */
#include "sim_faults.h"

#include <string.h>

volatile sig_atomic_t sim_signal_stop, sim_signal_resume;

static void on_usr1(int sig) { (void)sig; sim_signal_stop = 1; }
static void on_usr2(int sig) { (void)sig; sim_signal_resume = 1; }

void sim_faults_install_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sigemptyset(&sa.sa_mask);
    sa.sa_handler = on_usr1;
    sigaction(SIGUSR1, &sa, NULL);
    sa.sa_handler = on_usr2;
    sigaction(SIGUSR2, &sa, NULL);
}

void sim_faults_init(sim_faults *f, double p_drop, double p_dup, double p_corrupt, uint64_t seed)
{
    memset(f, 0, sizeof *f);
    f->p_drop = p_drop;
    f->p_dup = p_dup;
    f->p_corrupt = p_corrupt;
    sim_rng_seed(&f->rng, seed ^ 0x6661756C7473ull);
    f->serving = 1;
}

int sim_faults_schedule(sim_faults *f, double t, int stop)
{
    if (f->n_sched >= SIM_MAX_SCHEDULE) return -1;
    size_t i = f->n_sched++;
    while (i > 0 && f->at[i - 1] > t) {
        f->at[i] = f->at[i - 1];
        f->stop[i] = f->stop[i - 1];
        i--;
    }
    f->at[i] = t;
    f->stop[i] = stop;
    return 0;
}

static void flip(sim_rng *r, uint8_t *data, size_t len)
{
    if (!len) return;
    uint64_t bit = sim_rng_u64(r) % (len * 8);
    data[bit / 8] ^= (uint8_t)(1u << (bit % 8));
}

int sim_faults_frame(sim_faults *f, uint8_t *data, size_t len)
{
    f->seen++;
    /* always draw all three numbers, so that one probability does not shift the
     * random stream of the others */
    double a = sim_rng_uniform(&f->rng), b = sim_rng_uniform(&f->rng), c = sim_rng_uniform(&f->rng);
    if (a < f->p_drop) {
        f->dropped++;
        return 0;
    }
    if (c < f->p_corrupt && len) {
        flip(&f->rng, data, len);
        f->corrupted++;
    }
    if (b < f->p_dup) {
        f->duplicated++;
        return 2;
    }
    return 1;
}

int sim_faults_record(sim_faults *f, uint16_t *words, size_t n_words)
{
    f->seen++;
    double a = sim_rng_uniform(&f->rng), b = sim_rng_uniform(&f->rng), c = sim_rng_uniform(&f->rng);
    (void)b;
    if (a < f->p_drop) {
        f->dropped++;
        return 0;
    }
    if (c < f->p_corrupt && n_words > 1) {
        uint64_t bit = sim_rng_u64(&f->rng) % ((n_words - 1) * 16);
        words[1 + bit / 16] ^= (uint16_t)(1u << (bit % 16));
        f->corrupted++;
    }
    return 1;
}

int sim_faults_update(sim_faults *f, double t)
{
    int was = f->serving;
    while (f->next_sched < f->n_sched && f->at[f->next_sched] <= t) {
        f->serving = !f->stop[f->next_sched];
        f->next_sched++;
    }
    if (sim_signal_stop) {
        sim_signal_stop = 0;
        f->serving = 0;
    }
    if (sim_signal_resume) {
        sim_signal_resume = 0;
        f->serving = 1;
    }
    if (was && !f->serving) {
        f->stops++;
        return -1;
    }
    if (!was && f->serving) {
        f->resumes++;
        return 1;
    }
    return 0;
}
