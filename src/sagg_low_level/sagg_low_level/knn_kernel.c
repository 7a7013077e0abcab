/* The inner loops of the neighbour searches, compiled (for speed only: each replaces ~20-60 numpy
 * calls by one call, with the same answers bit for bit).
 *
 * approx(): the approximate k-nearest-neighbour search of the sample memory,
 * sagg_low_level.memory_search.KnnSearch._knn_approx (a bounded best-bin-first walk of the memory's
 * static-block index, FLANN's "checks", paper Sec. 3.3), over the arrays that
 * sagg_low_level.memory_index keeps, in one call instead of ~60 numpy calls for the same walk in
 * numpy. Its answers are that walk's:
 *
 *   - every distance is the memory's canonical one (sagg_low_level.memory_distance): the
 *     coordinates' squared differences summed in index order, sequentially, with the same IEEE
 *     operations numpy performs (subtract, multiply, add; no fused multiply-add: built with
 *     -ffp-contract=off), so boxes, points and ties compare exactly as in the numpy walk;
 *   - a box's lower bound per coordinate is max(lo - q, (-hi) - (-q), 0 - 0), as the walk formed
 *     it from the stored rows (lo, -hi, 0) and the query rows (q, -q, 0);
 *   - per box height the candidates are the kept nodes of the height above (in their order) and
 *     then the root groups; a node is kept when its bound is <= the buffer's k-th distance; when
 *     more than widths[h] are kept, those of smallest bound, ties by candidate order (the stable
 *     sort the walk used), in that order;
 *   - the answer is the first k of every scanned sample (buffer, kept leaves, the leaves of the
 *     query's exact duplicates) in (distance, index) order, a duplicate group's code standing for
 *     its members (at most k of them, the smallest indices): the walk's k-th-distance cut,
 *     group expansion and lexsort give exactly these.
 *   test/test_knn_kernel.py checks it against the numpy walk (kept there as the reference) on
 *   random memories with duplicates, ties and every index height.
 *
 * kd_build(), kd_query(): the exact search of the fixed-context learner
 * (sagg_low_level.tree_knn.TreeKnn): a kd tree with exact boxes over the samples stored at its
 * build, the samples stored since scanned; canonical distances, the first k by (distance, index)
 * (tested against the memory's exact search by test/test_tree_knn.py). Not a scipy cKDTree: its
 * query has a large fixed cost even for one 2-D row, and its own distances would need a check and
 * full scans to give the canonical answer.
 *
 * stored_refresh(), stored_keep(): the exact k nearest of a stored sample kept from one search to
 * the next (sagg_low_level.stored_knn.StoredKnn): the samples stored since merged into a kept
 * answer in (distance, index) order (tested against TreeKnn by test/test_stored_knn.py).
 *
 * boxes_holding(): ACTUATOR-RIAC's leaves whose context box holds the current context
 * (sagg_low_level.riac_leaves.RiacLeaves.compatible; test/test_riac_leaves.py checks it against the
 * tree walk it stands for).
 *
 * Loops run coordinate-major where they sweep runs of points (run_dists: numpy's order, and the
 * rows of these arrays are often a multiple of 4 KiB apart: a point-major loop would thrash a set
 * of the L1 cache). Plain C99 against the CPython API and the buffer protocol (no numpy headers).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sagg_kernel_buffers.h"

/* The loops over runs of points and boxes (run_dists, box_bounds) are compiled twice where GCC can
   choose at load time (x86-64, glibc: an ifunc): for AVX2 (4 doubles a vector) and for the baseline
   (SSE2, 2 doubles), the faster one picked for the processor at hand. Element-wise subtract,
   multiply, add and max give the same floats at any width (no fused multiply-add:
   -ffp-contract=off; each sum is still taken coordinate after coordinate), so the answers do not
   depend on the processor. Kept out of line elsewhere: inlined into its caller, GCC 12 leaves
   box_bounds' loops scalar. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__) && defined(__GLIBC__)
#define POINT_LOOPS __attribute__((target_clones("avx2", "default")))
#elif defined(__GNUC__)
#define POINT_LOOPS __attribute__((noinline))
#else
#define POINT_LOOPS
#endif

/* canonical squared distances to q of the columns c0 .. c0 + count - 1 of the dimension-major x
   (n rows of `stride` doubles) into out[0..count): coordinate-major (numpy's order, and the rows of
   these arrays are often a multiple of 4 KiB apart, so a point-major loop would thrash a set of the
   L1 cache); per column the squares are summed in coordinate order, as memory_distance defines */
POINT_LOOPS static void run_dists(const double *x, Py_ssize_t stride, Py_ssize_t c0, Py_ssize_t count, const double *q,
                      Py_ssize_t n, double *out) {
    const double *row = x + c0;
    for (Py_ssize_t j = 0; j < count; j++) {
        const double t = row[j] - q[0];
        out[j] = t * t;
    }
    for (Py_ssize_t d = 1; d < n; d++) {
        row = x + d * stride + c0;
        const double qd = q[d];
        for (Py_ssize_t j = 0; j < count; j++) {
            const double t = row[j] - qd;
            out[j] += t * t;
        }
    }
}

/* Hoare quickselect: moves the m first of a[0..n) in BEFORE's order to a[0..m), a[m - 1] the m-th
   (1 <= m <= n; keys distinct or plain values, no NaN). The m-th is an order statistic: the same
   whatever the algorithm. One body for doubles and candidates. */
#define QUICKSELECT(T, a, n, m, BEFORE)                      \
    do {                                                     \
        Py_ssize_t lo_ = 0, hi_ = (n) - 1;                   \
        const Py_ssize_t t_ = (m) - 1;                       \
        while (lo_ < hi_) {                                  \
            const T pivot_ = (a)[lo_ + (hi_ - lo_) / 2];     \
            Py_ssize_t i_ = lo_, j_ = hi_;                   \
            while (i_ <= j_) {                               \
                while (BEFORE((a)[i_], pivot_)) i_++;        \
                while (BEFORE(pivot_, (a)[j_])) j_--;        \
                if (i_ <= j_) {                              \
                    T x_ = (a)[i_];                          \
                    (a)[i_++] = (a)[j_];                     \
                    (a)[j_--] = x_;                          \
                }                                            \
            }                                                \
            if (t_ <= j_)                                    \
                hi_ = j_;                                    \
            else if (t_ >= i_)                               \
                lo_ = i_;                                    \
            else                                             \
                break;                                       \
        }                                                    \
    } while (0)

#define DOUBLE_BEFORE(x, y) ((x) < (y))

/* the k-th smallest of a[0..n) (1 <= k <= n, no NaN); reorders a */
static double select_kth(double *a, Py_ssize_t n, Py_ssize_t k) {
    QUICKSELECT(double, a, n, k, DOUBLE_BEFORE);
    return a[k - 1];
}

/* the larger of a, b, then of that and c, as the max instruction takes it (see box_bounds) */
static inline double max_sq_operand(double a, double b, double c) {
    const double x = a > b ? a : b;
    return x > c ? x : c;
}

/* the squared distances from q to the boxes of node groups[0..ng) (fan slots each; the stored
   rows lo, -hi, 0 of `slots` columns per coordinate) into lb[0 .. ng * fan): per slot,
   max(lo - q, (-hi) - (-q), 0 - 0) squared and summed coordinate after coordinate, the first
   coordinate on its own so that the inner loop over a group's fan slots has no branch (it
   vectorises); the same operations in the same order as the numpy walk. The maximum is taken as
   a > b ? a : b (the processor's max instruction) where numpy.maximum is a >= b ? a : b: they
   differ only for a == b == 0 of opposite signs, where both squares are +0, and the boxes and
   queries hold no NaN, so every square, hence every bound, is the same */
POINT_LOOPS static void box_bounds(const double *restrict lo, const double *restrict nhi, const double *restrict zero,
                       Py_ssize_t slots, const int64_t *groups, Py_ssize_t ng, Py_ssize_t fan, const double *q,
                       Py_ssize_t n, double *restrict lb) {
    for (Py_ssize_t d = 0; d < n; d++) {
        const Py_ssize_t o = d * slots;
        const double qd = q[d], nqd = -q[d];
        for (Py_ssize_t gi = 0; gi < ng; gi++) {
            const double *l = lo + o + (Py_ssize_t)groups[gi] * fan, *h = nhi + o + (Py_ssize_t)groups[gi] * fan;
            const double *z = zero + o + (Py_ssize_t)groups[gi] * fan;
            double *restrict out = lb + gi * fan;
            if (d == 0) {
                for (Py_ssize_t f = 0; f < fan; f++) {
                    const double v = max_sq_operand(l[f] - qd, h[f] - nqd, z[f] - 0.0);
                    out[f] = v * v;
                }
            } else {
                for (Py_ssize_t f = 0; f < fan; f++) {
                    const double v = max_sq_operand(l[f] - qd, h[f] - nqd, z[f] - 0.0);
                    out[f] += v * v;
                }
            }
        }
    }
}

/* candidates in (d, i) order: a distance or bound and a sample index (the answers) or a slot (the
   beam's nodes) */
typedef struct {
    double d;
    int64_t i;
} Cand;

typedef struct {
    Cand *c;
    Py_ssize_t n, cap;
} Cands;

static int cands_push(Cands *v, double d, int64_t i) {
    if (v->n == v->cap) {
        Py_ssize_t cap = v->cap ? 2 * v->cap : 256;
        Cand *c = realloc(v->c, sizeof(Cand) * cap);
        if (!c) return -1;
        v->c = c;
        v->cap = cap;
    }
    v->c[v->n].d = d;
    v->c[v->n++].i = i;
    return 0;
}

static int cmp_cand(const void *a, const void *b) {
    const Cand *x = a, *y = b;
    if (x->d < y->d) return -1;
    if (x->d > y->d) return 1;
    return x->i < y->i ? -1 : (x->i > y->i);
}

#define CAND_BEFORE(x, y) ((x).d < (y).d || ((x).d == (y).d && (x).i < (y).i))

/* c[0..n) sorted in (d, i) order (keys distinct, no NaN): insertion sort for the few (k, a beam's
   width) that the searches sort, qsort beyond; distinct keys have one order, whatever the sort */
static void sort_cands(Cand *c, Py_ssize_t n) {
    if (n > 64) {
        qsort(c, n, sizeof(Cand), cmp_cand);
        return;
    }
    for (Py_ssize_t j = 1; j < n; j++) {
        const Cand x = c[j];
        Py_ssize_t p = j;
        while (p > 0 && CAND_BEFORE(x, c[p - 1])) {
            c[p] = c[p - 1];
            p--;
        }
        c[p] = x;
    }
}

/* c[0..m) = the m first of c[0..n) in (d, i) order (m <= n; keys distinct, no NaN), sorted: a
   quickselect moves them to the front, then only they are sorted */
static void first_sorted(Cand *c, Py_ssize_t n, Py_ssize_t m) {
    if (m < n) QUICKSELECT(Cand, c, n, m, CAND_BEFORE);
    sort_cands(c, m);
}

/* the first k in (d, i) order of the candidates offered (keys distinct, no NaN), kept as a heap of
   at most k whose root is the last of them: an offer after the root is dropped at once, so a scan
   keeps k entries instead of every candidate within its bound (the same k, whatever the order of
   the offers: they are the first k of one total order) */
typedef struct {
    Cand *c;
    Py_ssize_t n, k;
} TopK;

/* the largest distance a candidate may have to enter (a tie enters when its index is smaller) */
static inline double topk_worst(const TopK *h) { return h->n < h->k ? INFINITY : h->c[0].d; }

static void topk_offer(TopK *h, double d, int64_t i) {
    const Cand x = {d, i};
    Cand *c = h->c;
    Py_ssize_t p;
    if (h->n < h->k) { /* room: sift up */
        p = h->n++;
        while (p > 0) {
            const Py_ssize_t u = (p - 1) / 2;
            if (!CAND_BEFORE(c[u], x)) break;
            c[p] = c[u];
            p = u;
        }
        c[p] = x;
        return;
    }
    if (!CAND_BEFORE(x, c[0])) return;
    p = 0; /* x replaces the root: sift down */
    for (;;) {
        const Py_ssize_t l = 2 * p + 1, r = l + 1;
        if (l >= h->n) break;
        const Py_ssize_t g = (r < h->n && CAND_BEFORE(c[l], c[r])) ? r : l;
        if (!CAND_BEFORE(x, c[g])) break;
        c[p] = c[g];
        p = g;
    }
    c[p] = x;
}

static int cmp_i64(const void *a, const void *b) {
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return x < y ? -1 : (x > y);
}

PyDoc_STRVAR(approx_doc,
"approx(q, k, buf_t, nb, ns, height, boxes, root_groups, widths, fan, leaf, pts, pidx, extra, dup,\n"
"       dup_off, out) -> int\n\n"
"The approximate k nearest of q (see KnnSearch._knn_approx) written into out[:k]. Returns the\n"
"number of leaves scanned s, or -1 - s when fewer than k samples were scanned (no answer).");

static PyObject *approx(PyObject *self, PyObject *args) {
    PyObject *oq, *obuf, *oboxes, *oroots, *owidths, *opts, *opidx, *oextra, *odup, *odupoff, *oout;
    Py_ssize_t k, nb, ns, height, fan, leaf;
    if (!PyArg_ParseTuple(args, "OnOnnnOOOnnOOOOOO", &oq, &k, &obuf, &nb, &ns, &height, &oboxes, &oroots,
                          &owidths, &fan, &leaf, &opts, &opidx, &oextra, &odup, &odupoff, &oout))
        return NULL;
    if (!PyList_Check(oboxes) || !PyList_Check(oroots)) {
        PyErr_SetString(PyExc_TypeError, "knn_kernel.approx: boxes and root_groups must be lists");
        return NULL;
    }
    if (k < 1 || fan < 1 || leaf < 1 || nb < 0 || height >= PyList_GET_SIZE(oboxes) ||
        height >= PyList_GET_SIZE(oroots)) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.approx: bad sizes");
        return NULL;
    }
    Buf bq = {0}, bbuf = {0}, bw = {0}, bpts = {0}, bpidx = {0}, bextra = {0}, bdup = {0}, bdoff = {0},
        bout = {0}, bbox = {0}, broot = {0};
    double *bd = NULL, *lb = NULL, *scratch = NULL;
    int64_t *sel = NULL, *groups = NULL, *keep = NULL;
    Cands cands = {NULL, 0, 0};
    TopK top = {NULL, 0, 0};
    PyObject *result = NULL;
    if (get_buf(oq, &bq, "q", "d", 8, 0) || get_buf(obuf, &bbuf, "buf_t", "d", 8, 0) ||
        get_buf(owidths, &bw, "widths", "q", 8, 0) || get_buf(opts, &bpts, "pts", "d", 8, 0) ||
        get_buf(opidx, &bpidx, "pidx", "q", 8, 0) || get_buf(oextra, &bextra, "extra", "q", 8, 0) ||
        get_buf(odup, &bdup, "dup", "q", 8, 0) || get_buf(odupoff, &bdoff, "dup_off", "q", 8, 0) ||
        get_buf(oout, &bout, "out", "q", 8, 1))
        goto done;
    const Py_ssize_t n = bq.view.len / 8;
    const double *q = bq.view.buf;
    if (bbuf.view.ndim != 2 || bbuf.view.shape[0] != n || nb > bbuf.view.shape[1] ||
        bout.view.len / 8 < k || bpts.view.ndim != 2 || bpts.view.shape[0] != n ||
        bpidx.view.len / 8 != bpts.view.shape[1] || bw.view.len / 8 <= height) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.approx: array shapes do not match");
        goto done;
    }
    const Py_ssize_t bcols = bbuf.view.shape[1];
    const double *buf = bbuf.view.buf;
    const int64_t *widths = bw.view.buf;

    /* the buffer: canonical distances of samples ns .. ns + nb - 1 */
    bd = malloc(sizeof(double) * (nb ? nb : 1));
    scratch = malloc(sizeof(double) * (nb ? nb : 1));
    if (!bd || !scratch) {
        PyErr_NoMemory();
        goto done;
    }
    run_dists(buf, bcols, 0, nb, q, n, bd);
    /* nodes farther than an upper bound of the k-th distance cannot contribute; with no bound yet,
       the largest float still drops the empty (infinite) padding boxes */
    if (nb >= k) memcpy(scratch, bd, sizeof(double) * nb);
    const double bound = nb >= k ? select_kth(scratch, nb, k) : DBL_MAX;

    Py_ssize_t nsel = -1; /* -1: no kept nodes (None) */
    for (Py_ssize_t h = height; h >= 0; h--) {
        if (get_buf(PyList_GET_ITEM(oroots, h), &broot, "root_groups[h]", "q", 8, 0) ||
            get_buf(PyList_GET_ITEM(oboxes, h), &bbox, "boxes[h]", "d", 8, 0))
            goto done;
        const int64_t *roots = broot.view.buf;
        const Py_ssize_t r = broot.view.len / 8;
        const Py_ssize_t ng = (nsel > 0 ? nsel : 0) + r;
        if (ng == 0) {
            nsel = -1;
            release(&broot);
            release(&bbox);
            continue;
        }
        int64_t *g2 = malloc(sizeof(int64_t) * ng);
        double *lb2 = malloc(sizeof(double) * ng * fan);
        int64_t *k2 = malloc(sizeof(int64_t) * ng * fan);
        free(groups);
        free(lb);
        free(keep);
        groups = g2;
        lb = lb2;
        keep = k2;
        if (!groups || !lb || !keep) {
            PyErr_NoMemory();
            goto done;
        }
        Py_ssize_t m = 0;
        for (Py_ssize_t j = 0; j < nsel; j++) groups[m++] = sel[j];
        for (Py_ssize_t j = 0; j < r; j++) groups[m++] = roots[j];
        const Py_ssize_t slots = bbox.view.len / 8 / (3 * n);
        const double *lo = bbox.view.buf, *nhi = lo + n * slots, *zero = nhi + n * slots;
        for (Py_ssize_t gi = 0; gi < ng; gi++)
            if (groups[gi] < 0 || ((Py_ssize_t)groups[gi] + 1) * fan > slots) {
                PyErr_SetString(PyExc_IndexError, "knn_kernel.approx: node group out of range");
                goto done;
            }
        box_bounds(lo, nhi, zero, slots, groups, ng, fan, q, n, lb);
        Py_ssize_t nk = 0;
        for (Py_ssize_t p = 0; p < ng * fan; p++)
            if (lb[p] <= bound) keep[nk++] = p;
        const Py_ssize_t cap = (Py_ssize_t)widths[h];
        if (nk > cap) { /* the cap of smallest bound, ties by candidate order, in that order */
            cands.n = 0;
            for (Py_ssize_t j = 0; j < nk; j++)
                if (cands_push(&cands, lb[keep[j]], keep[j])) goto nomem;
            first_sorted(cands.c, nk, cap);
            for (Py_ssize_t j = 0; j < cap; j++) keep[j] = cands.c[j].i;
            nk = cap;
            cands.n = 0;
        }
        int64_t *s2 = malloc(sizeof(int64_t) * (nk ? nk : 1));
        if (!s2) {
            PyErr_NoMemory();
            goto done;
        }
        for (Py_ssize_t j = 0; j < nk; j++) s2[j] = groups[keep[j] / fan] * fan + keep[j] % fan;
        free(sel);
        sel = s2;
        nsel = nk;
        release(&broot);
        release(&bbox);
    }
    /* the leaves holding exact duplicates of the query are always scanned */
    const Py_ssize_t nextra = bextra.view.len / 8;
    if (nextra) {
        int64_t *s2 = malloc(sizeof(int64_t) * ((nsel > 0 ? nsel : 0) + nextra));
        if (!s2) {
            PyErr_NoMemory();
            goto done;
        }
        Py_ssize_t m = 0;
        for (Py_ssize_t j = 0; j < nsel; j++) s2[m++] = sel[j];
        memcpy(s2 + m, bextra.view.buf, sizeof(int64_t) * nextra);
        m += nextra;
        qsort(s2, m, sizeof(int64_t), cmp_i64);
        Py_ssize_t u = 0;
        for (Py_ssize_t j = 0; j < m; j++)
            if (!u || s2[j] != s2[u - 1]) s2[u++] = s2[j];
        free(sel);
        sel = s2;
        nsel = u;
    }
    if (nsel < 0) nsel = 0;
    const Py_ssize_t npts = bpts.view.shape[1];
    const double *pts = bpts.view.buf;
    const int64_t *pidx = bpidx.view.buf;
    Py_ssize_t scanned = nb; /* samples scanned: empty leaf slots (NaN) do not count */
    /* the answer is the first k in (distance, index) order; the buffer's k-th distance is at least
       its k-th distance (k buffer samples are within it), so only candidates within it are
       offered (every scanned one, NaN excepted, when the buffer holds fewer than k), and of those
       the heap keeps the first k */
    const double within = nb >= k ? bound : INFINITY;
    top.c = malloc(sizeof(Cand) * k);
    top.k = k;
    if (!top.c) goto nomem;
    for (Py_ssize_t j = 0; j < nb; j++)
        if (bd[j] <= within) topk_offer(&top, bd[j], ns + j);
    double worst = topk_worst(&top);
    const int64_t *dup = bdup.view.buf, *dup_off = bdoff.view.buf;
    const Py_ssize_t ngroups = bdoff.view.len / 8 - 1;
    const Py_ssize_t ndup = bdup.view.len / 8;
    double *ld = malloc(sizeof(double) * leaf);
    if (!ld) goto nomem;
    for (Py_ssize_t j = 0; j < nsel; j++) {
        const Py_ssize_t s0 = (Py_ssize_t)sel[j] * leaf;
        if (sel[j] < 0 || s0 + leaf > npts) {
            free(ld);
            PyErr_SetString(PyExc_IndexError, "knn_kernel.approx: leaf out of range");
            goto done;
        }
        run_dists(pts, npts, s0, leaf, q, n, ld);
        Py_ssize_t filled = 0; /* empty slots (NaN) are not samples */
        for (Py_ssize_t e = 0; e < leaf; e++) filled += ld[e] == ld[e];
        scanned += filled;
        /* a candidate beyond the bound, or an empty slot (NaN), or after the k kept so far is
           dropped: s <= within and s <= worst, i.e. s <= the smaller of them */
        double lim = worst < within ? worst : within;
        for (Py_ssize_t e = 0; e < leaf; e++) {
            const double s = ld[e];
            if (!(s <= lim)) continue;
            const int64_t id = pidx[s0 + e];
            if (id >= 0) {
                topk_offer(&top, s, id);
            } else if (id < -1) { /* a duplicate group: its (first k) members */
                const int64_t g = -id - 2;
                int64_t a = g < ngroups ? dup_off[g] : 0, b = g < ngroups ? dup_off[g + 1] : -1;
                if (a < 0 || b < a || b > ndup) {
                    free(ld);
                    PyErr_SetString(PyExc_IndexError, "knn_kernel.approx: duplicate group out of range");
                    goto done;
                }
                if (b > a + k) b = a + k;
                for (int64_t x = a; x < b; x++) topk_offer(&top, s, dup[x]);
            }
            worst = topk_worst(&top);
            lim = worst < within ? worst : within;
        }
    }
    free(ld);
    if (scanned < k) { /* fewer than k samples scanned: no answer */
        result = PyLong_FromSsize_t(-1 - nsel);
        goto done;
    }
    if (top.n < k) { /* cannot happen: k scanned samples lie within the bound */
        PyErr_SetString(PyExc_RuntimeError, "knn_kernel.approx: fewer than k candidates");
        goto done;
    }
    sort_cands(top.c, k);
    int64_t *out = bout.view.buf;
    for (Py_ssize_t j = 0; j < k; j++) out[j] = top.c[j].i;
    result = PyLong_FromSsize_t(nsel);
    goto done;
nomem:
    PyErr_NoMemory();
done:
    free(bd);
    free(lb);
    free(scratch);
    free(cands.c);
    free(top.c);
    free(sel);
    free(groups);
    free(keep);
    release(&bq);
    release(&bbuf);
    release(&bw);
    release(&bpts);
    release(&bpidx);
    release(&bextra);
    release(&bdup);
    release(&bdoff);
    release(&bout);
    release(&bbox);
    release(&broot);
    return result;
}

/* ---------------------------------------------------------------- the exact kd tree (TreeKnn)

   A balanced kd tree over samples 0 .. nt - 1 of a store, stored implicitly: node i has children
   2i + 1 and 2i + 2, the root covers [0, nt), a node [s, e) splits at m = s + (e - s) / 2 along the
   coordinate of widest extent of its cell (the root's cell: its members' bounds; a child's: its
   parent's cut at the split value; the lowest such coordinate), its members ordered so that
   the first half holds the smallest by (coordinate, sample index); `depth` levels of splits (the
   fewest that leave at most TreeKnn's leafsize samples in a leaf, the nodes of the last level).
   Every node keeps the exact bounding box of its members. The samples are kept in tree order,
   dimension-major, so that a leaf is a run of columns. */

typedef struct {
    double v;
    int64_t i;
} KeyIdx;

#define KEY_BEFORE(x, y) ((x).v < (y).v || ((x).v == (y).v && (x).i < (y).i))

/* l, h = the coordinate-wise bounds of the rows perm[s0 .. e0) of x (n columns); +inf, -inf for
   no row: a box no query is near */
static void member_bounds(const double *x, const int64_t *perm, Py_ssize_t s0, Py_ssize_t e0, Py_ssize_t n,
                          double *l, double *h) {
    for (Py_ssize_t d = 0; d < n; d++) {
        l[d] = INFINITY;
        h[d] = -INFINITY;
    }
    for (Py_ssize_t j = s0; j < e0; j++) {
        const double *row = x + perm[j] * n;
        for (Py_ssize_t d = 0; d < n; d++) {
            if (row[d] < l[d]) l[d] = row[d];
            if (row[d] > h[d]) h[d] = row[d];
        }
    }
}

PyDoc_STRVAR(kd_build_doc,
"kd_build(x, depth, perm, pts_t, lo, hi, nstart, nend) -> None\n\n"
"Builds the exact kd tree of TreeKnn (see knn_kernel.c) over the rows of x (nt, n): perm (nt,) gets\n"
"the samples in tree order, pts_t (n, nt) their coordinates, lo and hi (2**(depth+1) - 1, n) the\n"
"nodes' boxes, nstart and nend (nodes,) their ranges of tree positions.");

static PyObject *kd_build(PyObject *self, PyObject *args) {
    PyObject *ox, *operm, *opts, *olo, *ohi, *ons, *one;
    Py_ssize_t depth;
    if (!PyArg_ParseTuple(args, "OnOOOOOO", &ox, &depth, &operm, &opts, &olo, &ohi, &ons, &one)) return NULL;
    Buf bx = {0}, bp = {0}, bt = {0}, blo = {0}, bhi = {0}, bns = {0}, bne = {0};
    KeyIdx *keys = NULL;
    PyObject *result = NULL;
    if (get_buf(ox, &bx, "x", "d", 8, 0) || get_buf(operm, &bp, "perm", "q", 8, 1) ||
        get_buf(opts, &bt, "pts_t", "d", 8, 1) || get_buf(olo, &blo, "lo", "d", 8, 1) ||
        get_buf(ohi, &bhi, "hi", "d", 8, 1) || get_buf(ons, &bns, "nstart", "q", 8, 1) ||
        get_buf(one, &bne, "nend", "q", 8, 1))
        goto done;
    if (bx.view.ndim != 2 || bx.view.shape[1] < 1 || depth < 0 || depth > 40) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.kd_build: x must be 2-D, >= 1 column; depth in [0, 40]");
        goto done;
    }
    const Py_ssize_t nt = bx.view.shape[0], n = bx.view.shape[1];
    const Py_ssize_t nodes = ((Py_ssize_t)2 << depth) - 1;
    if (bp.view.len / 8 != nt || bt.view.len / 8 != n * nt || blo.view.len / 8 != nodes * n ||
        bhi.view.len / 8 != nodes * n || bns.view.len / 8 != nodes || bne.view.len / 8 != nodes) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.kd_build: array shapes do not match");
        goto done;
    }
    const double *x = bx.view.buf;
    int64_t *perm = bp.view.buf, *ns = bns.view.buf, *ne = bne.view.buf;
    double *pts = bt.view.buf, *lo = blo.view.buf, *hi = bhi.view.buf;
    keys = malloc(sizeof(KeyIdx) * (nt ? nt : 1));
    if (!keys) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t j = 0; j < nt; j++) perm[j] = j;
    ns[0] = 0;
    ne[0] = nt;
    const Py_ssize_t first_leaf = nodes / 2; /* nodes below are split, the rest are leaves */
    /* top down: a node's cell (the root's: the bounds of all samples, perm being the identity here; a child's: its parent's cell cut
       at the split value) chooses its split coordinate, the widest of the cell (the lowest such);
       the cells are kept in lo / hi until the exact boxes replace them below */
    member_bounds(x, perm, 0, nt, n, lo, hi);
    for (Py_ssize_t i = 0; i < first_leaf; i++) {
        const Py_ssize_t s0 = ns[i], e0 = ne[i], m = s0 + (e0 - s0) / 2;
        const Py_ssize_t c1 = 2 * i + 1, c2 = 2 * i + 2;
        ns[c1] = s0;
        ne[c1] = m;
        ns[c2] = m;
        ne[c2] = e0;
        const double *l = lo + i * n, *h = hi + i * n;
        memcpy(lo + c1 * n, l, sizeof(double) * n);
        memcpy(hi + c1 * n, h, sizeof(double) * n);
        memcpy(lo + c2 * n, l, sizeof(double) * n);
        memcpy(hi + c2 * n, h, sizeof(double) * n);
        if (e0 - s0 < 2) continue;
        Py_ssize_t dim = 0;
        for (Py_ssize_t d = 1; d < n; d++)
            if (h[d] - l[d] > h[dim] - l[dim]) dim = d;
        for (Py_ssize_t j = s0; j < e0; j++) {
            keys[j - s0].v = x[perm[j] * n + dim];
            keys[j - s0].i = perm[j];
        }
        /* the first m - s0 by (coordinate, index) to the front: the lower child */
        QUICKSELECT(KeyIdx, keys, e0 - s0, m - s0, KEY_BEFORE);
        for (Py_ssize_t j = s0; j < e0; j++) perm[j] = keys[j - s0].i;
        /* the lower half's largest coordinate bounds both cells (the upper half's are >= it) */
        hi[c1 * n + dim] = keys[m - s0 - 1].v;
        lo[c2 * n + dim] = keys[m - s0 - 1].v;
    }
    /* bottom up: the exact boxes, a leaf's from its members, a split node's the union of its
       children's (an empty node's: +inf .. -inf, a box no query is near) */
    for (Py_ssize_t i = nodes - 1; i >= 0; i--) {
        double *l = lo + i * n, *h = hi + i * n;
        if (i >= first_leaf) {
            member_bounds(x, perm, ns[i], ne[i], n, l, h);
        } else {
            const double *l1 = lo + (2 * i + 1) * n, *h1 = hi + (2 * i + 1) * n;
            const double *l2 = lo + (2 * i + 2) * n, *h2 = hi + (2 * i + 2) * n;
            for (Py_ssize_t d = 0; d < n; d++) {
                l[d] = l1[d] < l2[d] ? l1[d] : l2[d];
                h[d] = h1[d] > h2[d] ? h1[d] : h2[d];
            }
        }
    }
    for (Py_ssize_t d = 0; d < n; d++)
        for (Py_ssize_t j = 0; j < nt; j++) pts[d * nt + j] = x[perm[j] * n + d];
    Py_INCREF(Py_None);
    result = Py_None;
done:
    free(keys);
    release(&bx);
    release(&bp);
    release(&bt);
    release(&blo);
    release(&bhi);
    release(&bns);
    release(&bne);
    return result;
}

/* a lower bound of the canonical squared distance from q to every point of the box [l, h]: per
   coordinate the gap max(l - q, q - h, 0) squared, summed in coordinate order. For a point p of
   the box, l - q <= p - q and q - h <= q - p (rounding is monotone), so each square is at most
   (p - q)^2 as run_dists forms it, and sums taken in the same order keep the inequality: no
   float slack is needed, and a node is skipped only when this bound exceeds the k-th distance */
static inline double box_gap(const double *l, const double *h, const double *q, Py_ssize_t n) {
    double s = 0.0;
    for (Py_ssize_t d = 0; d < n; d++) {
        const double g = max_sq_operand(l[d] - q[d], q[d] - h[d], 0.0);
        s = d ? s + g * g : g * g;
    }
    return s;
}

PyDoc_STRVAR(kd_query_doc,
"kd_query(qs, k, perm, pts_t, lo, hi, nstart, nend, depth, recent_t, nr, out) -> int\n\n"
"TreeKnn.query (see tree_knn.py): out[j] = the first k by (canonical distance, index) of the tree's\n"
"samples (kd_build's arrays) and the recent samples nt .. nt + nr - 1 (recent_t (n, >= nr)), for\n"
"every query row qs[j]. Returns the number of leaves scanned.");

static PyObject *kd_query(PyObject *self, PyObject *args) {
    PyObject *oqs, *opts, *operm, *olo, *ohi, *ons, *one, *orec, *oout;
    Py_ssize_t k, depth, nr;
    if (!PyArg_ParseTuple(args, "OnOOOOOOnOnO", &oqs, &k, &operm, &opts, &olo, &ohi, &ons, &one, &depth, &orec,
                          &nr, &oout))
        return NULL;
    Buf bq = {0}, bt = {0}, bp = {0}, blo = {0}, bhi = {0}, bns = {0}, bne = {0}, brec = {0}, bout = {0};
    TopK top = {NULL, 0, k};
    double *dist = NULL;
    Py_ssize_t *stack = NULL;
    double *gaps = NULL;
    PyObject *result = NULL;
    if (get_buf(oqs, &bq, "qs", "d", 8, 0) || get_buf(opts, &bt, "pts_t", "d", 8, 0) ||
        get_buf(operm, &bp, "perm", "q", 8, 0) || get_buf(olo, &blo, "lo", "d", 8, 0) ||
        get_buf(ohi, &bhi, "hi", "d", 8, 0) || get_buf(ons, &bns, "nstart", "q", 8, 0) ||
        get_buf(one, &bne, "nend", "q", 8, 0) || get_buf(orec, &brec, "recent_t", "d", 8, 0) ||
        get_buf(oout, &bout, "out", "q", 8, 1))
        goto done;
    if (bq.view.ndim != 2 || brec.view.ndim != 2 || depth < 0 || depth > 40) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.kd_query: qs and recent_t must be 2-D, depth in [0, 40]");
        goto done;
    }
    const Py_ssize_t b = bq.view.shape[0], n = bq.view.shape[1], nt = bp.view.len / 8;
    const Py_ssize_t rcols = brec.view.shape[1], nodes = ((Py_ssize_t)2 << depth) - 1;
    if (k < 1 || n < 1 || nr < 0 || nr > rcols || brec.view.shape[0] != n || bt.view.len / 8 != n * nt ||
        blo.view.len / 8 != nodes * n || bhi.view.len / 8 != nodes * n || bns.view.len / 8 != nodes ||
        bne.view.len / 8 != nodes || bout.view.len / 8 != b * k || nt + nr < k) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.kd_query: array shapes do not match");
        goto done;
    }
    const double *qs = bq.view.buf, *pts = bt.view.buf, *lo = blo.view.buf, *hi = bhi.view.buf;
    const double *rec = brec.view.buf;
    const int64_t *perm = bp.view.buf, *ns = bns.view.buf, *ne = bne.view.buf;
    int64_t *out = bout.view.buf;
    Py_ssize_t widest = nr; /* the distance scratch: the recent samples, or the largest leaf */
    for (Py_ssize_t i = nodes / 2; i < nodes; i++) {
        if (ns[i] < 0 || ne[i] < ns[i] || ne[i] > nt) {
            PyErr_SetString(PyExc_IndexError, "knn_kernel.kd_query: node range out of range");
            goto done;
        }
        if (ne[i] - ns[i] > widest) widest = ne[i] - ns[i];
    }
    dist = malloc(sizeof(double) * (widest ? widest : 1));
    top.c = malloc(sizeof(Cand) * k);
    stack = malloc(sizeof(Py_ssize_t) * (2 * depth + 2));
    gaps = malloc(sizeof(double) * (2 * depth + 2));
    if (!dist || !top.c || !stack || !gaps) {
        PyErr_NoMemory();
        goto done;
    }
    Py_ssize_t leaves = 0;
    for (Py_ssize_t j = 0; j < b; j++) {
        const double *q = qs + j * n;
        top.n = 0;
        run_dists(rec, rcols, 0, nr, q, n, dist);
        for (Py_ssize_t r = 0; r < nr; r++) topk_offer(&top, dist[r], nt + r);
        Py_ssize_t sp = 0;
        if (nt) {
            stack[sp] = 0;
            gaps[sp++] = box_gap(lo, hi, q, n);
        }
        while (sp) { /* depth first, the nearer child first; a node's bound is kept with it */
            --sp;
            const Py_ssize_t i = stack[sp];
            if (gaps[sp] > topk_worst(&top)) continue;
            if (i >= nodes / 2) {
                const Py_ssize_t s0 = ns[i], cnt = ne[i] - ns[i];
                leaves++;
                run_dists(pts, nt, s0, cnt, q, n, dist);
                for (Py_ssize_t e = 0; e < cnt; e++)
                    if (dist[e] <= topk_worst(&top)) topk_offer(&top, dist[e], perm[s0 + e]);
                continue;
            }
            const Py_ssize_t c1 = 2 * i + 1, c2 = 2 * i + 2;
            const double g1 = box_gap(lo + c1 * n, hi + c1 * n, q, n), g2 = box_gap(lo + c2 * n, hi + c2 * n, q, n);
            const double worst = topk_worst(&top);
            const Py_ssize_t near = g1 <= g2 ? c1 : c2, far = g1 <= g2 ? c2 : c1;
            const double gn = g1 <= g2 ? g1 : g2, gf = g1 <= g2 ? g2 : g1;
            if (gf <= worst) { /* the farther is pushed first, popped second */
                stack[sp] = far;
                gaps[sp++] = gf;
            }
            if (gn <= worst) {
                stack[sp] = near;
                gaps[sp++] = gn;
            }
        }
        if (top.n < k) { /* cannot happen: nt + nr >= k samples were offered or bounded */
            PyErr_SetString(PyExc_RuntimeError, "knn_kernel.kd_query: fewer than k candidates");
            goto done;
        }
        sort_cands(top.c, k);
        for (Py_ssize_t e = 0; e < k; e++) out[j * k + e] = top.c[e].i;
    }
    result = PyLong_FromSsize_t(leaves);
done:
    free(top.c);
    free(dist);
    free(stack);
    free(gaps);
    release(&bq);
    release(&bt);
    release(&bp);
    release(&blo);
    release(&bhi);
    release(&bns);
    release(&bne);
    release(&brec);
    release(&bout);
    return result;
}

/* canonical squared distance of the rows a and q of a row-major array (n coordinates each): the
   same operations, in the same order, as run_dists; given up once the partial sum is
   not below `worst` (adding a square never lowers a sum, so the whole distance could not be below
   it either: the partial sum is returned, >= worst); worst = INFINITY for the whole distance */
static inline double row_dist_below(const double *a, const double *q, Py_ssize_t n, double worst) {
    double t = a[0] - q[0];
    double s = t * t;
    for (Py_ssize_t d = 1; d < n && s < worst; d++) {
        t = a[d] - q[d];
        s += t * t;
    }
    return s;
}

PyDoc_STRVAR(stored_refresh_doc,
"stored_refresh(alpha, rows, k, limit, slot_of, n0, cnt, cidx, cd, out, miss) -> int\n\n"
"StoredKnn.query's cached answers (see stored_knn.py): for every row j of `rows` (indices of stored\n"
"samples, alpha's rows 0 .. len - 1 all stored) whose slot s = slot_of[rows[j]] holds the first\n"
"cnt[s] by (canonical distance, index) of samples 0 .. n0[s] - 1, and len - n0[s] <= limit: the\n"
"samples n0[s] .. len - 1 are merged in, the slot brought up to len, and its first k written to\n"
"out[j]. The other rows' positions j are written to miss[0 .. m); returns m.");

static PyObject *stored_refresh(PyObject *self, PyObject *args) {
    PyObject *oalpha, *orows, *oslot, *on0, *ocnt, *ocidx, *ocd, *oout, *omiss;
    Py_ssize_t k, limit;
    if (!PyArg_ParseTuple(args, "OOnnOOOOOOO", &oalpha, &orows, &k, &limit, &oslot, &on0, &ocnt, &ocidx, &ocd,
                          &oout, &omiss))
        return NULL;
    Buf ba = {0}, br = {0}, bs = {0}, bn0 = {0}, bcnt = {0}, bci = {0}, bcd = {0}, bout = {0}, bmiss = {0};
    PyObject *result = NULL;
    if (get_buf(oalpha, &ba, "alpha", "d", 8, 0) || get_buf(orows, &br, "rows", "q", 8, 0) ||
        get_buf(oslot, &bs, "slot_of", "q", 8, 0) || get_buf(on0, &bn0, "n0", "q", 8, 1) ||
        get_buf(ocnt, &bcnt, "cnt", "q", 8, 1) || get_buf(ocidx, &bci, "cidx", "q", 8, 1) ||
        get_buf(ocd, &bcd, "cd", "d", 8, 1) || get_buf(oout, &bout, "out", "q", 8, 1) ||
        get_buf(omiss, &bmiss, "miss", "q", 8, 1))
        goto done;
    if (ba.view.ndim != 2 || bci.view.ndim != 2 || bcd.view.ndim != 2) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.stored_refresh: alpha, cidx and cd must be 2-D");
        goto done;
    }
    const Py_ssize_t len = ba.view.shape[0], n = ba.view.shape[1], b = br.view.len / 8;
    const Py_ssize_t slots = bn0.view.len / 8, width = bci.view.shape[1];
    if (k < 1 || k > width || k > len || bcd.view.shape[1] != width || bci.view.shape[0] != slots ||
        bcd.view.shape[0] != slots || bcnt.view.len / 8 != slots || bs.view.len / 8 < len ||
        bout.view.len / 8 != b * k || bmiss.view.len / 8 < b) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.stored_refresh: array shapes do not match");
        goto done;
    }
    const double *alpha = ba.view.buf;
    const int64_t *rows = br.view.buf, *slot_of = bs.view.buf;
    int64_t *n0 = bn0.view.buf, *cnt = bcnt.view.buf, *cidx = bci.view.buf, *out = bout.view.buf;
    int64_t *miss = bmiss.view.buf;
    double *cd = bcd.view.buf;
    Py_ssize_t m = 0;
    for (Py_ssize_t j = 0; j < b; j++) {
        const int64_t r = rows[j];
        if (r < 0 || r >= len) {
            PyErr_SetString(PyExc_IndexError, "knn_kernel.stored_refresh: row out of range");
            goto done;
        }
        const int64_t s = slot_of[r];
        if (s < 0 || s >= slots || n0[s] > len || len - n0[s] > limit || cnt[s] < (n0[s] < k ? n0[s] : k)) {
            miss[m++] = j;
            continue;
        }
        const double *q = alpha + r * n;
        int64_t *ci = cidx + s * width;
        double *dd = cd + s * width;
        Py_ssize_t c = cnt[s];
        /* a newer sample has a larger index than every cached one: it goes after the cached entries
           of equal distance, so in (distance, index) order its place is after every d' <= d */
        for (int64_t i = n0[s]; i < len; i++) {
            const double worst = c == k ? dd[k - 1] : INFINITY;
            const double d = row_dist_below(alpha + i * n, q, n, worst);
            if (!(d < worst)) continue;
            Py_ssize_t p = c < k ? c : k - 1; /* the slot the last entry moves out of */
            while (p > 0 && dd[p - 1] > d) {
                dd[p] = dd[p - 1];
                ci[p] = ci[p - 1];
                p--;
            }
            dd[p] = d;
            ci[p] = i;
            if (c < k) c++;
        }
        cnt[s] = c;
        n0[s] = len;
        memcpy(out + j * k, ci, sizeof(int64_t) * k);
    }
    result = PyLong_FromSsize_t(m);
done:
    release(&ba);
    release(&br);
    release(&bs);
    release(&bn0);
    release(&bcnt);
    release(&bci);
    release(&bcd);
    release(&bout);
    release(&bmiss);
    return result;
}

PyDoc_STRVAR(stored_keep_doc,
"stored_keep(alpha, rows, ans, slots, n0, cnt, cidx, cd) -> None\n\n"
"Caches the exact answers ans (m, k) of the stored samples rows (m,) (see stored_knn.py): slot\n"
"slots[j] gets ans[j], their canonical distances to row rows[j], cnt = k and n0 = len(alpha).");

static PyObject *stored_keep(PyObject *self, PyObject *args) {
    PyObject *oalpha, *orows, *oans, *oslots, *on0, *ocnt, *ocidx, *ocd;
    if (!PyArg_ParseTuple(args, "OOOOOOOO", &oalpha, &orows, &oans, &oslots, &on0, &ocnt, &ocidx, &ocd))
        return NULL;
    Buf ba = {0}, br = {0}, bans = {0}, bsl = {0}, bn0 = {0}, bcnt = {0}, bci = {0}, bcd = {0};
    PyObject *result = NULL;
    if (get_buf(oalpha, &ba, "alpha", "d", 8, 0) || get_buf(orows, &br, "rows", "q", 8, 0) ||
        get_buf(oans, &bans, "ans", "q", 8, 0) || get_buf(oslots, &bsl, "slots", "q", 8, 0) ||
        get_buf(on0, &bn0, "n0", "q", 8, 1) || get_buf(ocnt, &bcnt, "cnt", "q", 8, 1) ||
        get_buf(ocidx, &bci, "cidx", "q", 8, 1) || get_buf(ocd, &bcd, "cd", "d", 8, 1))
        goto done;
    if (ba.view.ndim != 2 || bans.view.ndim != 2 || bci.view.ndim != 2 || bcd.view.ndim != 2) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.stored_keep: alpha, ans, cidx and cd must be 2-D");
        goto done;
    }
    const Py_ssize_t len = ba.view.shape[0], n = ba.view.shape[1], m = br.view.len / 8;
    const Py_ssize_t k = bans.view.shape[1], slots = bn0.view.len / 8, width = bci.view.shape[1];
    if (bans.view.shape[0] != m || bsl.view.len / 8 != m || k > width || bcd.view.shape[1] != width ||
        bci.view.shape[0] != slots || bcd.view.shape[0] != slots || bcnt.view.len / 8 != slots) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.stored_keep: array shapes do not match");
        goto done;
    }
    const double *alpha = ba.view.buf;
    const int64_t *rows = br.view.buf, *ans = bans.view.buf, *sl = bsl.view.buf;
    int64_t *n0 = bn0.view.buf, *cnt = bcnt.view.buf, *cidx = bci.view.buf;
    double *cd = bcd.view.buf;
    for (Py_ssize_t j = 0; j < m; j++) {
        const int64_t r = rows[j], s = sl[j];
        if (r < 0 || r >= len || s < 0 || s >= slots) {
            PyErr_SetString(PyExc_IndexError, "knn_kernel.stored_keep: row or slot out of range");
            goto done;
        }
        for (Py_ssize_t e = 0; e < k; e++) {
            const int64_t i = ans[j * k + e];
            if (i < 0 || i >= len) {
                PyErr_SetString(PyExc_IndexError, "knn_kernel.stored_keep: answer out of range");
                goto done;
            }
            cidx[s * width + e] = i;
            cd[s * width + e] = row_dist_below(alpha + i * n, alpha + r * n, n, INFINITY);
        }
        cnt[s] = k;
        n0[s] = len;
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    release(&ba);
    release(&br);
    release(&bans);
    release(&bsl);
    release(&bn0);
    release(&bcnt);
    release(&bci);
    release(&bcd);
    return result;
}

PyDoc_STRVAR(boxes_holding_doc,
"boxes_holding(x, lower_t, upper_t, out) -> int\n\n"
"The boxes that hold x (see riac_leaves.RiacLeaves.compatible): box j holds x when\n"
"lower_t[d, j] <= x[d] < upper_t[d, j] for every coordinate d (lower_t, upper_t: (n, boxes)).\n"
"Their indices, in decreasing order, are written to out[0 .. m); returns m.");

/* RiacLeaves.compatible's test: numpy's (lower <= x).all(0) & (x < upper).all(0) and
   flatnonzero(...)[::-1], the same comparisons, coordinate after coordinate over the boxes that
   still hold x (a fifth of them hold all 15 coordinates of the 15-DOF arm's context) */
static PyObject *boxes_holding(PyObject *self, PyObject *args) {
    PyObject *ox, *olo, *oup, *oout;
    if (!PyArg_ParseTuple(args, "OOOO", &ox, &olo, &oup, &oout)) return NULL;
    Buf bx = {0}, blo = {0}, bup = {0}, bout = {0};
    PyObject *result = NULL;
    if (get_buf(ox, &bx, "x", "d", 8, 0) || get_buf(olo, &blo, "lower_t", "d", 8, 0) ||
        get_buf(oup, &bup, "upper_t", "d", 8, 0) || get_buf(oout, &bout, "out", "q", 8, 1))
        goto done;
    const Py_ssize_t n = bx.view.len / 8;
    if (blo.view.ndim != 2 || bup.view.ndim != 2 || blo.view.shape[0] != n || bup.view.shape[0] != n ||
        blo.view.shape[1] != bup.view.shape[1] || bout.view.len / 8 < blo.view.shape[1]) {
        PyErr_SetString(PyExc_ValueError, "knn_kernel.boxes_holding: array shapes do not match");
        goto done;
    }
    const Py_ssize_t nb = blo.view.shape[1];
    const double *x = bx.view.buf, *lo = blo.view.buf, *up = bup.view.buf;
    int64_t *out = bout.view.buf;
    /* coordinate 0 over every box, then each coordinate over the boxes still in (in increasing
       order), written from the back so that the survivors end in decreasing order at out[0..m) */
    Py_ssize_t m = 0;
    if (n == 0) {
        for (Py_ssize_t j = nb - 1; j >= 0; j--) out[m++] = j;
    } else {
        const double x0 = x[0];
        for (Py_ssize_t j = nb - 1; j >= 0; j--)
            if (lo[j] <= x0 && x0 < up[j]) out[m++] = j;
        for (Py_ssize_t d = 1; d < n && m; d++) {
            const double xd = x[d], *lod = lo + d * nb, *upd = up + d * nb;
            Py_ssize_t w = 0;
            for (Py_ssize_t r = 0; r < m; r++) {
                const int64_t j = out[r];
                if (lod[j] <= xd && xd < upd[j]) out[w++] = j;
            }
            m = w;
        }
    }
    result = PyLong_FromSsize_t(m);
done:
    release(&bx);
    release(&blo);
    release(&bup);
    release(&bout);
    return result;
}

static PyMethodDef methods[] = {
    {"approx", approx, METH_VARARGS, approx_doc},
    {"kd_build", kd_build, METH_VARARGS, kd_build_doc},
    {"kd_query", kd_query, METH_VARARGS, kd_query_doc},
    {"stored_refresh", stored_refresh, METH_VARARGS, stored_refresh_doc},
    {"stored_keep", stored_keep, METH_VARARGS, stored_keep_doc},
    {"boxes_holding", boxes_holding, METH_VARARGS, boxes_holding_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "sagg_low_level.knn_kernel",
    "The neighbour searches' inner loops, compiled (see knn_kernel.c).", -1,
    methods,
};

PyMODINIT_FUNC PyInit_knn_kernel(void) { return PyModule_Create(&module); }
