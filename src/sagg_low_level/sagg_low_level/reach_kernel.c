/* The local model's small linear algebra, compiled (for speed only: each call replaces ~15-40
 * numpy calls). The Python functions of sagg_low_level/local_model.py stay the definition, with
 * their citations; these compute the same quantities in another order of operations (floats
 * differ in the last bits, never the semantics; test/test_reach_kernel.py checks every routine
 * against its Python reference on random cases):
 *
 *   jacobians(): local_model.local_jacobian, the least-squares Jacobian J(alpha) = dY / dA of a
 *     neighbour set (paper Sec. 3.3), for one or many index rows into the memory's arrays. The
 *     minimum-norm least-squares solution with numpy.linalg.lstsq's cut (singular values
 *     <= rcond * the largest treated as zero): a Householder QR of the k x n set; when
 *     1 / (||R||_F ||R^-1||_F) > rcond, a lower bound of sigma_min / sigma_max, no singular value
 *     is cut and the solution is R^-1 Q^T dY (back substitution); otherwise (and whenever k < n)
 *     the singular values of R (of the set itself when k < n) by one-sided Jacobi (Hestenes 1958;
 *     Demmel & Veselic 1992, SIAM J. Matrix Anal. Appl. 13(4)) on whichever of the matrix and its
 *     transpose has fewer columns, and the truncated SVD solution; singular values below
 *     eps * max(k, n) * the largest are cut whatever rcond (numerically zero: numpy's own results are
 *     noise there).
 *
 *   steps(): local_model.pseudo_inverse_step (paper Sec. 3.3, d_alpha = J^+ dy_next, singular
 *     values <= rcond * the largest cut) or, with damping lambda > 0, the damped least-squares
 *     step J^T (J J^T + lambda^2 I)^-1 dy (local_model.damped_steps), from the SVD of J^T by
 *     one-sided Jacobi: d_alpha = sum_j M_j (W_j^T dy) g_j, M_j = sigma_j U_j, g_j = 1/sigma_j^2
 *     (pinv) or 1/(sigma_j^2 + lambda^2) (damped); with clamp != 0 local_model.clamped_step's
 *     rounds (joint clamping and re-solving, Baerlocher & Boulic 2004), for one or many rows.
 *
 * Plain C99 against the CPython API and the buffer protocol (no numpy headers, no LAPACK).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sagg_kernel_buffers.h"

#define JACOBI_SWEEPS 60

/* One-sided Jacobi on the columns of the column-major r x c matrix a (column j at a + j * r), c <= r:
   rotates pairs of columns until every pair is orthogonal to working precision; v (c x c,
   column-major, starting as the identity) accumulates the rotations, so that a_in = a_out v^T with
   a_out's columns orthogonal: their norms are the singular values, a_out = U Sigma. A column whose
   squared norm falls to (eps ||a||_F)^2 is numerically zero (a rank-deficient a): its pairs are not
   rotated (they would never converge), and the cut of svd_solve drops it. Returns -1 when a holds
   a NaN or an infinity, else 0. */
static int jacobi_columns(double *a, Py_ssize_t r, Py_ssize_t c, double *v) {
    double frob2 = 0.0;
    for (Py_ssize_t i = 0; i < r * c; i++) frob2 += a[i] * a[i];
    if (!isfinite(frob2)) return -1;
    const double tiny2 = DBL_EPSILON * DBL_EPSILON * frob2;
    for (int sweep = 0; sweep < JACOBI_SWEEPS; sweep++) {
        int rotated = 0;
        for (Py_ssize_t p = 0; p + 1 < c; p++) {
            for (Py_ssize_t q = p + 1; q < c; q++) {
                double *ap = a + p * r, *aq = a + q * r;
                double alpha = 0.0, beta = 0.0, gamma = 0.0;
                for (Py_ssize_t i = 0; i < r; i++) {
                    alpha += ap[i] * ap[i];
                    beta += aq[i] * aq[i];
                    gamma += ap[i] * aq[i];
                }
                if (alpha <= tiny2 || beta <= tiny2) continue;
                if (gamma == 0.0 || fabs(gamma) <= DBL_EPSILON * sqrt(alpha * beta)) continue;
                rotated = 1;
                const double zeta = (beta - alpha) / (2.0 * gamma);
                const double t = (zeta >= 0.0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                const double cs = 1.0 / sqrt(1.0 + t * t), sn = cs * t;
                for (Py_ssize_t i = 0; i < r; i++) {
                    const double x = ap[i], y = aq[i];
                    ap[i] = cs * x - sn * y;
                    aq[i] = sn * x + cs * y;
                }
                double *vp = v + p * c, *vq = v + q * c;
                for (Py_ssize_t i = 0; i < c; i++) {
                    const double x = vp[i], y = vq[i];
                    vp[i] = cs * x - sn * y;
                    vq[i] = sn * x + cs * y;
                }
            }
        }
        if (!rotated) break;
    }
    return 0;
}

static void identity(double *v, Py_ssize_t c) {
    memset(v, 0, (size_t)(c * c) * sizeof(double));
    for (Py_ssize_t j = 0; j < c; j++) v[j * c + j] = 1.0;
}

static double column_norm(const double *a, Py_ssize_t r) {
    double s = 0.0;
    for (Py_ssize_t i = 0; i < r; i++) s += a[i] * a[i];
    return sqrt(s);
}

/* X = A^+ B (pinv: singular values <= rcond * the largest, and below eps * max(rows, cols) * the
   largest, cut) or, with lam > 0, the damped X = A^T (A A^T + lam^2 I)^-1 B: A the column-major
   rows x cols matrix a, B the column-major rows x m matrix b (leading dimension ldb), X the
   column-major cols x m matrix x. The SVD is taken by one-sided Jacobi on whichever of A and A^T has
   fewer columns (only min(rows, cols) singular values exist). With P the matrix rotated (P = P_out
   V^T, P_out's columns sigma_j times singular vectors), and g_j = 1 / sigma_j^2 (pinv) or
   1 / (sigma_j^2 + lam^2) (damped):
     P = A:   x_c = sum_j V_j (P_out_j . b_c) g_j;   P = A^T:  x_c = sum_j P_out_j (V_j . b_c) g_j.
   work: rows * cols + max(rows, cols)^2 doubles; a is overwritten when P = A. Returns -1 on a
   non-finite A, else 0. */
static int svd_solve(double *a, Py_ssize_t rows, Py_ssize_t cols, const double *b, Py_ssize_t ldb,
                     Py_ssize_t m, double rcond, double lam, double *work, double *x) {
    const int transposed = cols > rows;
    double *p = a, *v = work + rows * cols;
    Py_ssize_t pr = rows, pc = cols; /* the rotated matrix: pr x pc, pc <= pr */
    if (transposed) {
        p = work;
        pr = cols;
        pc = rows;
        for (Py_ssize_t j = 0; j < cols; j++)
            for (Py_ssize_t i = 0; i < rows; i++) p[i * cols + j] = a[j * rows + i];
    }
    identity(v, pc);
    if (jacobi_columns(p, pr, pc, v)) return -1;
    double smax = 0.0;
    for (Py_ssize_t j = 0; j < pc; j++) {
        const double sj = column_norm(p + j * pr, pr);
        if (sj > smax) smax = sj;
    }
    const double cut = fmax(rcond, DBL_EPSILON * (double)(rows > cols ? rows : cols)) * smax;
    memset(x, 0, (size_t)(cols * m) * sizeof(double));
    for (Py_ssize_t j = 0; j < pc; j++) {
        const double *pj = p + j * pr, *vj = v + j * pc;
        const double sj = column_norm(pj, pr);
        double g;
        if (lam > 0.0)
            g = 1.0 / (sj * sj + lam * lam);
        else if (sj > cut && sj > 0.0)
            g = 1.0 / (sj * sj);
        else
            continue;
        for (Py_ssize_t c = 0; c < m; c++) {
            const double *bc = b + c * ldb;
            double *xc = x + c * cols;
            double proj = 0.0;
            if (!transposed) {
                for (Py_ssize_t i = 0; i < rows; i++) proj += pj[i] * bc[i];
                const double f = proj * g;
                for (Py_ssize_t i = 0; i < cols; i++) xc[i] += f * vj[i];
            } else {
                for (Py_ssize_t i = 0; i < rows; i++) proj += vj[i] * bc[i];
                const double f = proj * g;
                for (Py_ssize_t i = 0; i < cols; i++) xc[i] += f * pj[i];
            }
        }
    }
    return 0;
}

/* Workspace of one least-squares fit: k x n set, m right-hand sides. */
typedef struct {
    double *a;    /* k x n, column-major */
    double *b;    /* k x m, column-major */
    double *rinv; /* n x n */
    double *x;    /* n x m */
    double *work; /* svd_solve's: k * n + max(k, n)^2 */
} Lsq;

static int lsq_alloc(Lsq *w, Py_ssize_t k, Py_ssize_t n, Py_ssize_t m) {
    const Py_ssize_t big = k > n ? k : n;
    const size_t total = (size_t)(k * n + k * m + n * n + n * m + k * n + big * big);
    w->a = malloc(total * sizeof(double));
    if (!w->a) return -1;
    w->b = w->a + k * n;
    w->rinv = w->b + k * m;
    w->x = w->rinv + n * n;
    w->work = w->x + n * m;
    return 0;
}

/* The minimum-norm least-squares X (n x m, column-major in w->x) of A X = B, A = w->a (k x n), B =
   w->b (k x m), singular values <= rcond * the largest cut (see the file's head). A and B are
   overwritten. Returns -1 on a non-finite A, else 0. */
static int lstsq(Lsq *w, Py_ssize_t k, Py_ssize_t n, Py_ssize_t m, double rcond) {
    double *a = w->a, *b = w->b, *x = w->x;
    if (k < n) /* fewer rows than unknowns: the truncated SVD of A itself */
        return svd_solve(a, k, n, b, k, m, rcond, 0.0, w->work, x);
    const double cut = fmax(rcond, DBL_EPSILON * (double)k); /* A's cut, whatever rcond: eps * k */
    /* Householder QR: A = Q R, B <- Q^T B; R in the upper triangle of a */
    for (Py_ssize_t j = 0; j < n; j++) {
        double *aj = a + j * k;
        double norm = 0.0;
        for (Py_ssize_t i = j; i < k; i++) norm += aj[i] * aj[i];
        norm = sqrt(norm);
        if (norm == 0.0) continue;
        const double alpha = aj[j] > 0.0 ? -norm : norm; /* R_jj; v = a_j - alpha e_j */
        const double v0 = aj[j] - alpha;
        const double vnorm2 = norm * norm - aj[j] * aj[j] + v0 * v0;
        aj[j] = v0;                                      /* v kept in place below the diagonal */
        for (Py_ssize_t c = j + 1; c < n + m; c++) {
            double *col = c < n ? a + c * k : b + (c - n) * k;
            double dot = 0.0;
            for (Py_ssize_t i = j; i < k; i++) dot += aj[i] * col[i];
            const double f = 2.0 * dot / vnorm2;
            for (Py_ssize_t i = j; i < k; i++) col[i] -= f * aj[i];
        }
        aj[j] = alpha;
        for (Py_ssize_t i = j + 1; i < k; i++) aj[i] = 0.0;
    }
    /* compact R (n x n) and c = (Q^T B)[:n] to n rows */
    for (Py_ssize_t j = 1; j < n; j++) memmove(a + j * n, a + j * k, (size_t)n * sizeof(double));
    for (Py_ssize_t j = 0; j < m; j++) memmove(b + j * n, b + j * k, (size_t)n * sizeof(double));
    /* full rank beyond doubt? 1 / (||R||_F ||R^-1||_F) <= sigma_min / sigma_max */
    int invertible = 1;
    double rf = 0.0;
    for (Py_ssize_t j = 0; j < n; j++) {
        if (a[j * n + j] == 0.0) invertible = 0;
        for (Py_ssize_t i = 0; i <= j; i++) rf += a[j * n + i] * a[j * n + i];
    }
    if (!isfinite(rf)) return -1;
    if (invertible) {
        double *ri = w->rinv; /* R^-1, upper triangular, column-major */
        memset(ri, 0, (size_t)(n * n) * sizeof(double));
        double inf = 0.0;
        for (Py_ssize_t j = 0; j < n; j++) {
            ri[j * n + j] = 1.0 / a[j * n + j];
            for (Py_ssize_t i = j - 1; i >= 0; i--) {
                double s = 0.0;
                for (Py_ssize_t l = i + 1; l <= j; l++) s += a[l * n + i] * ri[j * n + l];
                ri[j * n + i] = -s / a[i * n + i];
            }
            for (Py_ssize_t i = 0; i <= j; i++) inf += ri[j * n + i] * ri[j * n + i];
        }
        if (isfinite(inf) && 1.0 / sqrt(rf * inf) > cut) {
            for (Py_ssize_t c = 0; c < m; c++) { /* back substitution R x = c */
                const double *bc = b + c * n;
                double *xc = x + c * n;
                for (Py_ssize_t i = n - 1; i >= 0; i--) {
                    double s = bc[i];
                    for (Py_ssize_t l = i + 1; l < n; l++) s -= a[l * n + i] * xc[l];
                    xc[i] = s / a[i * n + i];
                }
            }
            return 0;
        }
    }
    /* the truncated SVD of R (its singular values are A's, so is the cut) */
    return svd_solve(a, n, n, b, n, m, cut, 0.0, w->work, x);
}

static const char jacobians_doc[] =
    "jacobians(da, dy, idx, rcond, out): local_model.local_jacobian(da[idx[b]], dy[idx[b]], rcond) "
    "into out[b] (m x n) for every row b of idx (B x k int64, or one row of k); da (N x n), dy (N x m) "
    "float64, C-contiguous.";

static PyObject *jacobians(PyObject *self, PyObject *args) {
    PyObject *oda, *ody, *oidx, *oout;
    double rcond;
    if (!PyArg_ParseTuple(args, "OOOdO", &oda, &ody, &oidx, &rcond, &oout)) return NULL;
    Buf bda = {0}, bdy = {0}, bidx = {0}, bout = {0};
    Lsq w = {0};
    PyObject *result = NULL;
    if (get_buf(oda, &bda, "da", "d", 8, 0) || get_buf(ody, &bdy, "dy", "d", 8, 0) ||
        get_buf(oidx, &bidx, "idx", "q", 8, 0) || get_buf(oout, &bout, "out", "d", 8, 1))
        goto done;
    if (bda.view.ndim != 2 || bdy.view.ndim != 2 || bidx.view.ndim < 1 || bidx.view.ndim > 2) {
        PyErr_SetString(PyExc_ValueError, "reach_kernel.jacobians: da, dy must be 2-D, idx 1-D or 2-D");
        goto done;
    }
    const Py_ssize_t total = bda.view.shape[0], n = bda.view.shape[1], m = bdy.view.shape[1];
    const Py_ssize_t nb = bidx.view.ndim == 2 ? bidx.view.shape[0] : 1;
    const Py_ssize_t k = bidx.view.shape[bidx.view.ndim - 1];
    if (bdy.view.shape[0] < total || k < 1 || bout.view.len / 8 != nb * m * n) {
        PyErr_SetString(PyExc_ValueError, "reach_kernel.jacobians: array shapes do not match");
        goto done;
    }
    const double *da = bda.view.buf, *dy = bdy.view.buf;
    const int64_t *idx = bidx.view.buf;
    double *out = bout.view.buf;
    for (Py_ssize_t i = 0; i < nb * k; i++) {
        if (idx[i] < 0 || idx[i] >= total) {
            PyErr_SetString(PyExc_IndexError, "reach_kernel.jacobians: index out of range");
            goto done;
        }
    }
    if (lsq_alloc(&w, k, n, m)) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t r = 0; r < nb; r++) {
        const int64_t *row = idx + r * k;
        for (Py_ssize_t i = 0; i < k; i++) {
            const double *src = da + row[i] * n, *ys = dy + row[i] * m;
            for (Py_ssize_t j = 0; j < n; j++) w.a[j * k + i] = src[j];
            for (Py_ssize_t c = 0; c < m; c++) w.b[c * k + i] = ys[c];
        }
        if (lstsq(&w, k, n, m, rcond)) {
            PyErr_SetString(PyExc_ValueError, "reach_kernel.jacobians: a neighbour set holds a NaN or an infinity");
            goto done;
        }
        double *jac = out + r * m * n; /* J = X^T: row c of J is column c of X */
        memcpy(jac, w.x, (size_t)(m * n) * sizeof(double));
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    free(w.a);
    release(&bda);
    release(&bdy);
    release(&bidx);
    release(&bout);
    return result;
}

/* Workspace of the steps of one row: J m x n. */
typedef struct {
    double *cols; /* J restricted to the free joints: m x r, column-major */
    double *work; /* svd_solve's: m * n + max(m, n)^2 */
    double *step; /* n */
    double *dalpha, *target;
    int64_t *idx;
    char *free_;
} Steps;

static int steps_alloc(Steps *w, Py_ssize_t m, Py_ssize_t n) {
    const Py_ssize_t big = m > n ? m : n;
    w->cols = malloc((size_t)(m * n + m * n + big * big + 2 * n + m) * sizeof(double));
    w->idx = malloc((size_t)n * sizeof(int64_t));
    w->free_ = malloc((size_t)n);
    if (!w->cols || !w->idx || !w->free_) return -1;
    w->work = w->cols + m * n;
    w->step = w->work + m * n + big * big;
    w->dalpha = w->step + n;
    w->target = w->dalpha + n;
    return 0;
}

static void steps_free(Steps *w) {
    free(w->cols);
    free(w->idx);
    free(w->free_);
}

/* step (r) = J_free^+ target (pinv, singular values <= rcond * max cut) or the damped step, with J_free
   = the columns idx[0..r) of the row-major m x n jac. Returns -1 on a non-finite J. */
static int solve_step(Steps *w, const double *jac, Py_ssize_t m, Py_ssize_t n, const int64_t *idx,
                      Py_ssize_t r, const double *target, double rcond, double lam) {
    double *cols = w->cols; /* J_free, column-major: column t (length m) = joint idx[t] */
    for (Py_ssize_t t = 0; t < r; t++)
        for (Py_ssize_t c = 0; c < m; c++) cols[t * m + c] = jac[c * n + idx[t]];
    return svd_solve(cols, m, r, target, m, 1, rcond, lam, w->work, w->step);
}

/* One row of steps(): local_model.clamped_step (clamp) or pseudo_inverse_step into out (n). Returns
   -1 on a non-finite J, else 0. */
static int step_row(Steps *w, const double *jac, Py_ssize_t m, Py_ssize_t n, const double *dy,
                     const double *alpha, const double *lo, const double *up, double rcond, double lam,
                     int clamp, double *out) {
    for (Py_ssize_t j = 0; j < n; j++) w->idx[j] = j;
    if (solve_step(w, jac, m, n, w->idx, n, dy, rcond, lam)) return -1;
    int over_any = 0;
    if (clamp)
        for (Py_ssize_t j = 0; j < n; j++) {
            const double v = alpha[j] + w->step[j];
            if (v > up[j] || v < lo[j]) over_any = 1;
        }
    if (!over_any) {
        memcpy(out, w->step, (size_t)n * sizeof(double));
        return 0;
    }
    /* the rounds of local_model.clamp_rounds; the first round's solve is the step above */
    double *dalpha = w->dalpha;
    memset(dalpha, 0, (size_t)n * sizeof(double));
    memset(w->free_, 1, (size_t)n);
    Py_ssize_t r = n;
    for (Py_ssize_t round = 0; round < n; round++) {
        int any = 0;
        for (Py_ssize_t t = 0; t < r; t++) {
            const Py_ssize_t j = w->idx[t];
            const double v = alpha[j] + w->step[t];
            dalpha[j] = w->step[t];
            if (v > up[j] || v < lo[j]) {
                any = 1;
                dalpha[j] = fmin(fmax(v, lo[j]), up[j]) - alpha[j];
                w->free_[j] = 0;
            }
        }
        if (!any) break;
        r = 0;
        for (Py_ssize_t j = 0; j < n; j++)
            if (w->free_[j]) w->idx[r++] = j;
        if (!r) break;
        for (Py_ssize_t c = 0; c < m; c++) {
            double s = 0.0;
            for (Py_ssize_t j = 0; j < n; j++)
                if (!w->free_[j]) s += jac[c * n + j] * dalpha[j];
            w->target[c] = dy[c] - s;
        }
        solve_step(w, jac, m, n, w->idx, r, w->target, rcond, lam); /* J is finite: checked above */
    }
    memcpy(out, dalpha, (size_t)n * sizeof(double));
    return 0;
}

static const char steps_doc[] =
    "steps(jacs, dys, alphas, lower, upper, rcond, damping, clamp, out): for every row b, "
    "local_model.clamped_step(jacs[b], dys[b], alphas[b], lower, upper, rcond, damping) (clamp true) "
    "or pseudo_inverse_step(jacs[b], dys[b], rcond, damping) (clamp false) into out[b]; jacs (B x m x "
    "n), dys (B x m), alphas and out (B x n), lower and upper (n), float64, C-contiguous.";

static PyObject *steps(PyObject *self, PyObject *args) {
    PyObject *ojac, *ody, *oal, *olo, *oup, *oout;
    double rcond, lam;
    int clamp;
    if (!PyArg_ParseTuple(args, "OOOOOddpO", &ojac, &ody, &oal, &olo, &oup, &rcond, &lam, &clamp, &oout))
        return NULL;
    Buf bj = {0}, bd = {0}, ba = {0}, bl = {0}, bu = {0}, bo = {0};
    Steps w = {0};
    PyObject *result = NULL;
    if (get_buf(ojac, &bj, "jacs", "d", 8, 0) || get_buf(ody, &bd, "dys", "d", 8, 0) ||
        get_buf(oal, &ba, "alphas", "d", 8, 0) || get_buf(olo, &bl, "lower", "d", 8, 0) ||
        get_buf(oup, &bu, "upper", "d", 8, 0) || get_buf(oout, &bo, "out", "d", 8, 1))
        goto done;
    const Py_ssize_t n = bl.view.len / 8;
    const Py_ssize_t nb = n ? bo.view.len / 8 / n : 0;
    const Py_ssize_t m = nb ? bd.view.len / 8 / nb : 0;
    if (n < 1 || nb < 1 || m < 1 || bu.view.len != bl.view.len || bo.view.len / 8 != nb * n ||
        ba.view.len / 8 != nb * n || bd.view.len / 8 != nb * m || bj.view.len / 8 != nb * m * n) {
        PyErr_SetString(PyExc_ValueError, "reach_kernel.steps: array shapes do not match");
        goto done;
    }
    if (steps_alloc(&w, m, n)) {
        PyErr_NoMemory();
        goto done;
    }
    const double *jac = bj.view.buf, *dy = bd.view.buf, *al = ba.view.buf;
    double *out = bo.view.buf;
    for (Py_ssize_t b = 0; b < nb; b++) {
        if (step_row(&w, jac + b * m * n, m, n, dy + b * m, al + b * n, bl.view.buf, bu.view.buf, rcond, lam,
                     clamp, out + b * n)) {
            PyErr_SetString(PyExc_ValueError, "reach_kernel.steps: a Jacobian holds a NaN or an infinity");
            goto done;
        }
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    steps_free(&w);
    release(&bj);
    release(&bd);
    release(&ba);
    release(&bl);
    release(&bu);
    release(&bo);
    return result;
}

static PyMethodDef methods[] = {
    {"jacobians", jacobians, METH_VARARGS, jacobians_doc},
    {"steps", steps, METH_VARARGS, steps_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "sagg_low_level.reach_kernel",
    "The local model's small linear algebra, compiled (see reach_kernel.c).", -1, methods,
};

PyMODINIT_FUNC PyInit_reach_kernel(void) { return PyModule_Create(&module); }
