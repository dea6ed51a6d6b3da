/* The interface of plant_kernel.c: its structs and entry points, the one source of truth for the
 * C file (which includes it) and for the cffi declarations of design/plant/kernel.py (which read
 * this file with the preprocessor lines stripped).  The layouts are documented in plant_kernel.c. */
#ifndef SJ_PLANT_KERNEL_H
#define SJ_PLANT_KERNEL_H

/* ---- Fixed-step scheme (fixed_step.py) ---- */
typedef struct {
    int n, l, m, ny, levels, books;    /* books: 0 leaves the work integrals alone (NaN) */
    double step;
    const double *phi, *g0, *g1, *G, *book;   /* discretisation and work integrals per level */
    const double *ET, *HT, *Vy, *Dy, *two_xi_w;
    const double *s0, *s1, *s2, *fc, *fd, *vs, *arm, *bound;
    double *work;                      /* scratch: 5n + 7l + l*l doubles */
} sj_plant;

typedef struct {
    double *x, *q, *v, *phi, *u, *fn;
    double work_in, work_joints, work_damping;
    double failed_step, failed_residual;            /* set when a solve fails */
} sj_state;

typedef struct {
    double *v, *u, *fn, *phi, *sensors, *energy, *works;
} sj_record;

void sj_set_normal_force(const sj_plant *p, sj_state *s, const double *normal_force);
void sj_start(const sj_plant *p, sj_state *s, const double *w0);
void sj_measure(const sj_plant *p, const sj_state *s, double *sensors);
void sj_record_row(const sj_plant *p, const sj_state *s, const sj_record *r, long row);
long sj_run(const sj_plant *p, sj_state *s, const double *w, long steps, long k0, long record_every,
            const sj_record *r);

/* ---- Stick-exact scheme (stick_exact.py) ---- */
typedef struct {
    const double *phi, *g0, *g1, *Gv, *Gp;
} sj_stick_step;

/* Three step lengths: level 0 the long step H, level 1 H/ratio[0], level 2 (the short step)
 * H/(ratio[0] ratio[1]); a level is tried where every joint is quiet for it (kappa, beta[level]). */
typedef struct {
    int N, Np, n2, l, m, ny;                  /* Np: N rounded up to a multiple of four */
    int ratio[2];
    double kappa, beta[2];
    sj_stick_step level[3];
    const double *Cv, *Cy;                    /* (l, n2), (ny, n2) */
    const double *s0, *s1, *s2, *fc, *fd, *vs, *arm;
    double *work;                             /* scratch: 2Np + 2N + 14l + l*l doubles */
} sj_stick;

typedef struct {
    double *z, *d, *v, *u, *fn;
    long steps[3];                            /* steps taken per level */
    double failed_step, failed_residual;
} sj_stick_state;

void sj_stick_set_normal_force(const sj_stick *p, sj_stick_state *s, const double *normal_force);
void sj_stick_record_row(const sj_stick *p, const sj_stick_state *s, const sj_record *r, long row);
long sj_stick_run(const sj_stick *p, sj_stick_state *s, const double *w, long w_rows, long longs, long k0,
                  long record_every, const sj_record *r, double H);

#endif
