/* The EM of a Gaussian mixture, compiled (for speed only): sagg_goal_generator.gaussian_mixture.em
 * (Dempster, Laird & Rubin 1977; Bishop 2006 Sec. 9.2.2; scikit-learn's GaussianMixture step for
 * step) in one call instead of ~25 numpy calls per iteration. The numpy functions of
 * gaussian_mixture.py stay the definition; this computes the same quantities in another order of
 * operations (the Mahalanobis distance by forward substitution with the covariance's Cholesky
 * factor L instead of a product with L^-T), and test/test_gaussian_mixture.py checks it against
 * them and against scikit-learn.
 *
 * em(data, resp, full, reg_covar, tol, max_iter, weights, means, covariances, precisions_cholesky)
 *   data (N x D), resp (N x K: the initial responsibilities), all float64 C-contiguous; the four
 *   outputs (K), (K x D), (K x D x D) or, diagonal, (K x D), same for the precision factors.
 *   Returns (iterations, converged, lower bound), or None when a covariance is not positive
 *   definite (gaussian_mixture.em_compiled raises the reference's MixtureFitError then).
 *
 * nearest(points, q): the index of the row of points (N x D) nearest to q (D) in squared Euclidean
 *   distance, the first of equals: alp_gmm.absolute_learning_progress's search of the goal history
 *   (numpy's argmin of einsum's row sums of (p - q)^2: for up to 4 terms the same sums as here, so the
 *   same index, tested with many exact ties; D > 4 is refused: einsum's unrolled sums differ there).
 *
 * Plain C99 against the CPython API and the buffer protocol (no numpy headers).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sagg_kernel_buffers.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif
#define TINY (10.0 * DBL_EPSILON) /* scikit-learn's guard on a component's weight sum */

typedef struct {
    Py_ssize_t n, d, k;
    int full;
    const double *x; /* n x d */
    double *w, *mu, *cov, *chol; /* k; k x d; k x d x d (or k x d); the covariances' Cholesky factors */
    double *resp, *nk, *diff; /* n x k; k; d */
} Em;

/* The M-step (gaussian_mixture.gaussian_parameters): nk, means, covariances from em->resp;
   weights normalised by `total` (n at the start, the sum of nk after). */
static void m_step(Em *e, double reg, int first) {
    const Py_ssize_t n = e->n, d = e->d, k = e->k;
    double sum = 0.0;
    for (Py_ssize_t c = 0; c < k; c++) {
        double s = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) s += e->resp[i * k + c];
        e->nk[c] = s + TINY;
        sum += e->nk[c];
        double *mu = e->mu + c * d;
        for (Py_ssize_t j = 0; j < d; j++) mu[j] = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) {
            const double r = e->resp[i * k + c];
            for (Py_ssize_t j = 0; j < d; j++) mu[j] += r * e->x[i * d + j];
        }
        for (Py_ssize_t j = 0; j < d; j++) mu[j] /= e->nk[c];
        if (e->full) {
            double *cv = e->cov + c * d * d;
            memset(cv, 0, (size_t)(d * d) * sizeof(double));
            for (Py_ssize_t i = 0; i < n; i++) {
                const double r = e->resp[i * k + c];
                for (Py_ssize_t j = 0; j < d; j++) e->diff[j] = e->x[i * d + j] - mu[j];
                for (Py_ssize_t a = 0; a < d; a++)
                    for (Py_ssize_t b = 0; b <= a; b++) cv[a * d + b] += r * e->diff[a] * e->diff[b];
            }
            for (Py_ssize_t a = 0; a < d; a++) {
                for (Py_ssize_t b = 0; b <= a; b++) {
                    cv[a * d + b] /= e->nk[c];
                    cv[b * d + a] = cv[a * d + b];
                }
                cv[a * d + a] += reg;
            }
        } else {
            double *cv = e->cov + c * d;
            for (Py_ssize_t j = 0; j < d; j++) cv[j] = 0.0;
            for (Py_ssize_t i = 0; i < n; i++) {
                const double r = e->resp[i * k + c];
                for (Py_ssize_t j = 0; j < d; j++) {
                    const double t = e->x[i * d + j] - mu[j];
                    cv[j] += r * t * t;
                }
            }
            for (Py_ssize_t j = 0; j < d; j++) cv[j] = cv[j] / e->nk[c] + reg;
        }
    }
    const double total = first ? (double)n : sum;
    for (Py_ssize_t c = 0; c < k; c++) e->w[c] = e->nk[c] / total;
}

/* Cholesky factors L of the covariances (lower, row-major; diagonal: the standard deviations).
   -1 when one is not positive definite. */
static int factor(Em *e) {
    const Py_ssize_t d = e->d;
    for (Py_ssize_t c = 0; c < e->k; c++) {
        if (!e->full) {
            for (Py_ssize_t j = 0; j < d; j++) {
                const double v = e->cov[c * d + j];
                if (!(v > 0.0)) return -1;
                e->chol[c * d + j] = sqrt(v);
            }
            continue;
        }
        const double *a = e->cov + c * d * d;
        double *l = e->chol + c * d * d;
        memset(l, 0, (size_t)(d * d) * sizeof(double));
        for (Py_ssize_t i = 0; i < d; i++) {
            for (Py_ssize_t j = 0; j <= i; j++) {
                double s = a[i * d + j];
                for (Py_ssize_t t = 0; t < j; t++) s -= l[i * d + t] * l[j * d + t];
                if (i == j) {
                    if (!(s > 0.0)) return -1;
                    l[i * d + i] = sqrt(s);
                } else {
                    l[i * d + j] = s / l[j * d + j];
                }
            }
        }
    }
    return 0;
}

/* The E-step (gaussian_mixture.weighted_log_prob, logsumexp, responsibilities): em->resp, and the
   mean over the points of log sum_k pi_k N(x | mu_k, Sigma_k). */
static double e_step(Em *e) {
    const Py_ssize_t n = e->n, d = e->d, k = e->k;
    const double half_log_2pi = 0.5 * (double)d * log(2.0 * M_PI);
    double *ld = e->nk; /* log pi_k - log det L_k, per component (nk is rebuilt by the M-step) */
    for (Py_ssize_t c = 0; c < k; c++) {
        double s = log(e->w[c]);
        for (Py_ssize_t j = 0; j < d; j++) s -= log(e->full ? e->chol[c * d * d + j * d + j] : e->chol[c * d + j]);
        ld[c] = s;
    }
    double total = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *xi = e->x + i * d;
        double *ri = e->resp + i * k, top = -INFINITY;
        for (Py_ssize_t c = 0; c < k; c++) {
            const double *mu = e->mu + c * d;
            double maha = 0.0;
            if (e->full) { /* z = L^-1 (x - mu), forward substitution */
                const double *l = e->chol + c * d * d;
                for (Py_ssize_t a = 0; a < d; a++) {
                    double s = xi[a] - mu[a];
                    for (Py_ssize_t t = 0; t < a; t++) s -= l[a * d + t] * e->diff[t];
                    e->diff[a] = s / l[a * d + a];
                    maha += e->diff[a] * e->diff[a];
                }
            } else {
                const double *sd = e->chol + c * d;
                for (Py_ssize_t a = 0; a < d; a++) {
                    const double z = (xi[a] - mu[a]) / sd[a];
                    maha += z * z;
                }
            }
            ri[c] = -half_log_2pi - 0.5 * maha + ld[c];
            if (ri[c] > top) top = ri[c];
        }
        double s = 0.0; /* logsumexp; the responsibilities exp(r - norm) = exp(r - top) / s */
        for (Py_ssize_t c = 0; c < k; c++) {
            ri[c] = exp(ri[c] - top);
            s += ri[c];
        }
        for (Py_ssize_t c = 0; c < k; c++) ri[c] /= s;
        total += top + log(s);
    }
    return total / (double)n;
}

static PyObject *em(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *ox, *oresp, *ow, *omu, *ocov, *oprec;
    int full;
    double reg, tol;
    Py_ssize_t max_iter;
    if (!PyArg_ParseTuple(args, "OOpddnOOOO", &ox, &oresp, &full, &reg, &tol, &max_iter, &ow, &omu, &ocov, &oprec))
        return NULL;
    Buf bx = {0}, br = {0}, bw = {0}, bm = {0}, bc = {0}, bp = {0};
    Em e = {0};
    PyObject *result = NULL;
    if (get_buf(ox, &bx, "data", "d", 8, 0) || get_buf(oresp, &br, "resp", "d", 8, 0) ||
        get_buf(ow, &bw, "weights", "d", 8, 1) || get_buf(omu, &bm, "means", "d", 8, 1) ||
        get_buf(ocov, &bc, "covariances", "d", 8, 1) || get_buf(oprec, &bp, "precisions_cholesky", "d", 8, 1))
        goto done;
    if (bx.view.ndim != 2 || br.view.ndim != 2 || br.view.shape[0] != bx.view.shape[0]) {
        PyErr_SetString(PyExc_ValueError, "em_kernel.em: data (N x D) and resp (N x K) must be 2-D with N rows");
        goto done;
    }
    e.n = bx.view.shape[0];
    e.d = bx.view.shape[1];
    e.k = br.view.shape[1];
    e.full = full;
    const Py_ssize_t csize = full ? e.k * e.d * e.d : e.k * e.d;
    if (max_iter < 1) {
        PyErr_SetString(PyExc_ValueError, "em_kernel.em: max_iter must be at least 1");
        goto done;
    }
    if (e.n < 1 || e.d < 1 || e.k < 1 || bw.view.len / 8 != e.k || bm.view.len / 8 != e.k * e.d ||
        bc.view.len / 8 != csize || bp.view.len / 8 != csize) {
        PyErr_SetString(PyExc_ValueError, "em_kernel.em: array shapes do not match");
        goto done;
    }
    e.x = bx.view.buf;
    e.w = bw.view.buf;
    e.mu = bm.view.buf;
    e.cov = bc.view.buf;
    e.chol = malloc((size_t)(csize + e.n * e.k + e.k + e.d) * sizeof(double));
    if (!e.chol) {
        PyErr_NoMemory();
        goto done;
    }
    e.resp = e.chol + csize;
    e.nk = e.resp + e.n * e.k;
    e.diff = e.nk + e.k;
    memcpy(e.resp, br.view.buf, (size_t)(e.n * e.k) * sizeof(double));
    m_step(&e, reg, 1);
    if (factor(&e)) goto not_pd;
    double bound = -INFINITY;
    Py_ssize_t it = 0;
    int converged = 0;
    for (it = 1; it <= max_iter; it++) {
        const double prev = bound;
        bound = e_step(&e);
        m_step(&e, reg, 0);
        if (factor(&e)) goto not_pd;
        if (fabs(bound - prev) < tol) {
            converged = 1;
            break;
        }
    }
    if (it > max_iter) it = max_iter;
    /* the precisions' Cholesky factors of scikit-learn: (L^-1)^T (upper), or 1 / sd */
    double *prec = bp.view.buf;
    for (Py_ssize_t c = 0; c < e.k; c++) {
        if (!full) {
            for (Py_ssize_t j = 0; j < e.d; j++) prec[c * e.d + j] = 1.0 / e.chol[c * e.d + j];
            continue;
        }
        const double *l = e.chol + c * e.d * e.d;
        double *p = prec + c * e.d * e.d; /* p[i][j] = (L^-1)[j][i] */
        memset(p, 0, (size_t)(e.d * e.d) * sizeof(double));
        for (Py_ssize_t j = 0; j < e.d; j++) { /* column j of L^-1: forward substitution of e_j */
            for (Py_ssize_t a = j; a < e.d; a++) {
                double s = a == j ? 1.0 : 0.0;
                for (Py_ssize_t t = j; t < a; t++) s -= l[a * e.d + t] * p[j * e.d + t];
                p[j * e.d + a] = s / l[a * e.d + a];
            }
        }
    }
    result = Py_BuildValue("nOd", it, converged ? Py_True : Py_False, bound);
    goto done;
not_pd:
    result = Py_NewRef(Py_None);
done:
    free(e.chol);
    release(&bx);
    release(&br);
    release(&bw);
    release(&bm);
    release(&bc);
    release(&bp);
    return result;
}

static PyObject *nearest(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *op, *oq;
    if (!PyArg_ParseTuple(args, "OO", &op, &oq)) return NULL;
    Buf bp = {0}, bq = {0};
    PyObject *result = NULL;
    if (get_buf(op, &bp, "points", "d", 8, 0) || get_buf(oq, &bq, "q", "d", 8, 0)) goto done;
    const Py_ssize_t d = bq.view.len / 8, n = d ? bp.view.len / 8 / d : 0;
    if (bq.view.ndim != 1 || bp.view.ndim != 2 || bp.view.shape[1] != d || d < 1 || d > 4 || n < 1) {
        PyErr_SetString(PyExc_ValueError, "em_kernel.nearest: points (N x D, N >= 1, D <= 4) and q (D) do not match");
        goto done;
    }
    const double *p = bp.view.buf, *q = bq.view.buf;
    Py_ssize_t best = 0;
    double best_d = INFINITY;
    for (Py_ssize_t i = 0; i < n; i++) {
        double s = 0.0;
        for (Py_ssize_t j = 0; j < d; j++) {
            const double t = p[i * d + j] - q[j];
            s += t * t;
        }
        if (s < best_d || (i == 0)) {
            best_d = s;
            best = i;
        }
    }
    result = PyLong_FromSsize_t(best);
done:
    release(&bp);
    release(&bq);
    return result;
}

static PyMethodDef methods[] = {
    {"em", em, METH_VARARGS, "The EM of a Gaussian mixture (see em_kernel.c)."},
    {"nearest", nearest, METH_VARARGS, "The index of the nearest row (see em_kernel.c)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "sagg_goal_generator.em_kernel",
    "The alp-gmm teacher's EM and nearest-goal search, compiled (see em_kernel.c).", -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit_em_kernel(void) { return PyModule_Create(&module); }
