/* A hand-written C peer of jaxeac's grid-world runner, for same-run speed comparisons.
 *
 * One seed per OpenMP iteration (`schedule(dynamic)`), each with its own RNG and its
 * own agent tables; the tables live in a per-thread workspace that is reset for every
 * seed, so they stay in L1/L2. Everything follows SPEC (the pinned ids G1–G7, E1–E7):
 *
 *   G3  start cell uniform among the free non-goal cells (Lemire's unbiased bounded draw);
 *   G4  moves from precomputed tables (next state, bumped, reward per (s, a));
 *   G5  at most C chances per trial;
 *   (1) softmax over p(s, ·)/τ, sampled by inverse CDF exactly as
 *       jaxeac.algorithm.agent.sample_softmax (smallest a with u·Σw < cumsum(w)[a]);
 *   (3) δ = r + γ·V(s') − V(s), V(s') = 0 at the goal (terminal);
 *   (2) V(s) += α·δ, (4) p(s, a) += β·δ;
 *   E1  (a) remembered success action (a lookup: no softmax, no random number),
 *       (b) some but not all actions flagged → softmax over the unflagged ones,
 *       (c) else plain softmax;
 *   E2  learn only on E1(c) steps (variant `learn_on_memory`: every step);
 *   E3  goal check after every step;
 *   E4  after a success, write the trial's (s, a) in order, last write wins;
 *   E5  r̃ = −1 on a bump, else 1/(1 + ‖s' − g‖₂) once the goal is known (this step
 *       included), else 0;
 *   E6  after a failed trial, flag (s_c, a_c) where r̃(c|t) < r̃(c|t−1) for every c in
 *       both trials (variant `within_trial`: r̃(c|t) < r̃(c−1|t), c ≥ 1);
 *   E7  dense tables: success action per state (int8, −1 = none), 4 failure flags per
 *       state packed into one byte.
 *
 * Arithmetic is float32 as in jaxeac (compile with -ffp-contract=off so that
 * r + γ·V(s') − V(s) is rounded like the JAX code, without fused multiply-adds).
 *
 * Randomness: seed i of a run with root seed R uses splitmix64 seeded from (R, i), so a
 * seed's results do not depend on the number of seeds or threads beside it. The numbers
 * are not jaxeac's: the peer agrees with jaxeac in distribution only.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#ifdef _OPENMP
#include <omp.h>
#endif

#define N_ACTIONS 4

/* Algorithm flags (bit set) */
#define F_SUCCESS 1       /* success memory (E1(a), E4) */
#define F_FAILURE 2       /* failure memory (E1(b), E6) */
#define F_LEARN_MEMORY 4  /* E2 variant: learn on every step */
#define F_WITHIN_TRIAL 8  /* E6 variant: compare with the previous chance of the same trial */

typedef struct {
    int n_states, goal, n_starts, trials, chances;
    const int32_t *next_state; /* [S*4] */
    const uint8_t *bumped;     /* [S*4] */
    const float *reward;       /* [S*4] */
    const float *shaped;       /* [S]: 1/(1 + dist to goal), float32 */
    const int32_t *starts;     /* [n_starts] */
    float alpha, beta, gamma, tau;
    int unit_tau;
} Problem;

typedef struct {
    float *prefs;     /* [S*4] */
    float *values;    /* [S] */
    int8_t *success;  /* [S] */
    uint8_t *failure; /* [S], bit a = flag of action a */
    int32_t *states;  /* [C] */
    int8_t *actions;  /* [C] */
    float *rt, *prev_rt; /* [C] */
} Work;

/* --- RNG: splitmix64 ---------------------------------------------------------------------- */

static inline uint64_t mix64(uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

static inline uint64_t next64(uint64_t *state) {
    *state += 0x9E3779B97F4A7C15ULL;
    return mix64(*state);
}

/* uniform float32 in [0, 1): 24 random bits */
static inline float uniform01(uint64_t *state) {
    return (float)(next64(state) >> 40) * 0x1.0p-24f;
}

/* uniform integer in [0, n), unbiased (Lemire 2019) */
static inline uint32_t bounded(uint64_t *state, uint32_t n) {
    uint64_t m = (next64(state) >> 32) * (uint64_t)n;
    uint32_t low = (uint32_t)m;
    if (low < n) {
        uint32_t threshold = (uint32_t)(-n) % n;
        while (low < threshold) {
            m = (next64(state) >> 32) * (uint64_t)n;
            low = (uint32_t)m;
        }
    }
    return (uint32_t)(m >> 32);
}

/* The RNG state of seed `index` of a run with root seed `root` (shared with numba_peer.py). */
static inline uint64_t seed_state(uint64_t root, uint64_t index) {
    return mix64(mix64(root ^ 0x6A09E667F3BCC909ULL) + index * 0x9E3779B97F4A7C15ULL);
}

/* --- (1): inverse-CDF softmax sample over the actions whose bit is set in `allowed` ------- */

static inline int sample_softmax(const float *p, unsigned allowed, float tau, int unit_tau, float u) {
    float logit[N_ACTIONS], w[N_ACTIONS];
    float top = -INFINITY;
    for (int a = 0; a < N_ACTIONS; a++) {
        logit[a] = unit_tau ? p[a] : p[a] / tau; /* p(s, a)/τ as jaxeac */
        if (((allowed >> a) & 1u) && logit[a] > top) top = logit[a];
    }
    for (int a = 0; a < N_ACTIONS; a++) w[a] = ((allowed >> a) & 1u) ? expf(logit[a] - top) : 0.0f;
    float c1 = w[0] + w[1];
    float c2 = c1 + w[2];
    float c3 = c2 + w[3];
    float target = u * c3;
    int a = (w[0] <= target) + (c1 <= target) + (c2 <= target) + (c3 <= target);
    return a < N_ACTIONS - 1 ? a : N_ACTIONS - 1;
}

/* --- one seed ----------------------------------------------------------------------------- */

static inline void run_one(const Problem *P, Work *W, const int flags, uint64_t rng,
                           uint8_t *out_success, int32_t *out_steps, int8_t *out_policy,
                           float *out_prefs, float *out_values, int32_t *out_total_success,
                           int64_t *out_total_steps, int32_t *out_first) {
    const int S = P->n_states, C = P->chances, goal = P->goal;
    const int use_success = flags & F_SUCCESS, use_failure = flags & F_FAILURE;
    const int learn_memory = flags & F_LEARN_MEMORY, within = flags & F_WITHIN_TRIAL;
    const int record = use_success || use_failure;
    const float alpha = P->alpha, beta = P->beta, gamma = P->gamma;
    float *prefs = W->prefs, *values = W->values;
    int8_t *succ = W->success;
    uint8_t *fail = W->failure;
    memset(prefs, 0, sizeof(float) * (size_t)S * N_ACTIONS);
    memset(values, 0, sizeof(float) * (size_t)S);
    if (use_success) memset(succ, -1, (size_t)S);
    if (use_failure) memset(fail, 0, (size_t)S);
    float *rt = W->rt, *prev_rt = W->prev_rt;
    int prev_len = 0, goal_known = 0, total_success = 0, first = -1;
    int64_t total_steps = 0;

    for (int t = 0; t < P->trials; t++) {
        int s = P->starts[bounded(&rng, (uint32_t)P->n_starts)]; /* G3 */
        int len = 0, reached = 0;
        for (int c = 0; c < C; c++) {
            int a, learn = 1;
            int remembered = use_success ? succ[s] : -1;
            if (remembered >= 0) { /* E1(a) */
                a = remembered;
                learn = 0;
            } else {
                unsigned allowed = 0xFu;
                if (use_failure) {
                    unsigned f = fail[s];
                    if (f != 0u && f != 0xFu) { /* E1(b) */
                        allowed = ~f & 0xFu;
                        learn = 0;
                    }
                }
                a = sample_softmax(prefs + (size_t)s * N_ACTIONS, allowed, P->tau, P->unit_tau,
                                   uniform01(&rng));
            }
            if (learn_memory) learn = 1; /* E2 variant */
            const int move = s * N_ACTIONS + a;
            const int s2 = P->next_state[move]; /* G4 */
            const int terminal = s2 == goal;   /* E3 */
            if (learn) {                       /* E2: (3), (2), (4) */
                float v_next = terminal ? 0.0f : values[s2];
                float delta = (P->reward[move] + gamma * v_next) - values[s];
                values[s] += alpha * delta;
                prefs[move] += beta * delta;
            }
            if (record) {
                if (terminal) goal_known = 1; /* E5: this step included */
                W->states[c] = s;
                W->actions[c] = (int8_t)a;
                rt[c] = P->bumped[move] ? -1.0f : (goal_known ? P->shaped[s2] : 0.0f);
            }
            len = c + 1;
            s = s2;
            if (terminal) {
                reached = 1;
                break;
            }
        }
        if (reached) {
            total_success++;
            if (first < 0) first = t;
            if (use_success) /* E4: chronological order, last write wins */
                for (int c = 0; c < len; c++) succ[W->states[c]] = W->actions[c];
        } else if (use_failure) { /* E6 */
            if (within) {
                for (int c = 1; c < len; c++)
                    if (rt[c] < rt[c - 1]) fail[W->states[c]] |= (uint8_t)(1u << W->actions[c]);
            } else {
                int m = len < prev_len ? len : prev_len;
                for (int c = 0; c < m; c++)
                    if (rt[c] < prev_rt[c]) fail[W->states[c]] |= (uint8_t)(1u << W->actions[c]);
            }
        }
        if (record) {
            float *tmp = rt;
            rt = prev_rt;
            prev_rt = tmp;
            prev_len = len;
        }
        total_steps += len;
        if (out_success) out_success[t] = (uint8_t)reached;
        if (out_steps) out_steps[t] = len;
    }
    W->rt = rt;
    W->prev_rt = prev_rt;
    *out_total_success = total_success;
    *out_total_steps = total_steps;
    *out_first = first;
    if (out_policy) { /* G7: memory action where there is one, else argmax of preferences */
        for (int st = 0; st < S; st++) {
            int best = 0;
            for (int a = 1; a < N_ACTIONS; a++)
                if (prefs[st * N_ACTIONS + a] > prefs[st * N_ACTIONS + best]) best = a;
            out_policy[st] = (int8_t)((use_success && succ[st] >= 0) ? succ[st] : best);
        }
    }
    if (out_prefs) memcpy(out_prefs, prefs, sizeof(float) * (size_t)S * N_ACTIONS);
    if (out_values) memcpy(out_values, values, sizeof(float) * (size_t)S);
}

/* Specialised copies for the common algorithms, so the flag tests fold away. */
#define RUN(FLAGS) \
    run_one(&P, &W, (FLAGS), rng, succ_i, steps_i, pol_i, prefs_i, values_i, out_total_success + i, \
            out_total_steps + i, out_first + i)

int jaxeac_peer_openmp(void) {
#ifdef _OPENMP
    return 1;
#else
    return 0;
#endif
}

int jaxeac_peer_max_threads(void) {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

/* Run `n_seeds` seeds. Per-seed outputs may be NULL (then they are skipped), except the totals.
 * Returns 0 on success, −1 if a workspace could not be allocated. */
int jaxeac_peer_run(int n_states, int goal, const int32_t *next_state, const uint8_t *bumped,
                    const float *reward, const float *shaped, const int32_t *starts, int n_starts,
                    int flags, int trials, int chances, float alpha, float beta, float gamma,
                    float temperature, int64_t n_seeds, uint64_t root_seed, int threads,
                    uint8_t *out_success, int32_t *out_steps, int8_t *out_policy, float *out_prefs,
                    float *out_values, int32_t *out_total_success, int64_t *out_total_steps,
                    int32_t *out_first) {
    Problem P = {n_states, goal, n_starts, trials, chances, next_state, bumped, reward, shaped, starts,
                 alpha, beta, gamma, temperature, temperature == 1.0f};
    int failed = 0;
#ifndef _OPENMP
    (void)threads;
#else
    if (threads <= 0) threads = omp_get_max_threads();
#pragma omp parallel num_threads(threads) reduction(| : failed)
#endif
    {
        Work W = {0};
        const size_t S = (size_t)n_states, C = (size_t)chances;
        void *block = malloc(sizeof(float) * S * N_ACTIONS + sizeof(float) * S + S + S +
                             sizeof(int32_t) * C + C + 2 * sizeof(float) * C + 64);
        if (!block) {
            failed = 1;
        } else {
            char *q = (char *)block;
            W.prefs = (float *)q; q += sizeof(float) * S * N_ACTIONS;
            W.values = (float *)q; q += sizeof(float) * S;
            W.rt = (float *)q; q += sizeof(float) * C;
            W.prev_rt = (float *)q; q += sizeof(float) * C;
            W.states = (int32_t *)q; q += sizeof(int32_t) * C;
            W.success = (int8_t *)q; q += S;
            W.failure = (uint8_t *)q; q += S;
            W.actions = (int8_t *)q;
        }
#ifdef _OPENMP
#pragma omp for schedule(dynamic, 8)
#endif
        for (int64_t i = 0; i < n_seeds; i++) {
            if (!block) continue;
            uint64_t rng = seed_state(root_seed, (uint64_t)i);
            uint8_t *succ_i = out_success ? out_success + i * trials : NULL;
            int32_t *steps_i = out_steps ? out_steps + i * trials : NULL;
            int8_t *pol_i = out_policy ? out_policy + i * n_states : NULL;
            float *prefs_i = out_prefs ? out_prefs + i * n_states * N_ACTIONS : NULL;
            float *values_i = out_values ? out_values + i * n_states : NULL;
            switch (flags) {
            case 0: RUN(0); break;
            case F_SUCCESS | F_FAILURE: RUN(F_SUCCESS | F_FAILURE); break;
            default: RUN(flags); break;
            }
        }
        free(block);
    }
    return failed ? -1 : 0;
}
