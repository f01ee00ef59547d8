/* fw's compiled kernel: the numerics of the robot's 1 kHz cycle.
 *
 * Python spends a microsecond or more per numpy call on 7-element arrays, and one
 * cycle of the robot's loop made ~60 of them (the differential IK, the capsule
 * distances). This kernel does the same arithmetic in one call each, on float64
 * buffers (numpy arrays, C-contiguous), with the same formulas as the Python it
 * replaces (components/domain/ik.py, components/domain/distance.py), which stay as
 * the reference the specs compare it with and as the fallback where no C compiler
 * built it. It holds no state and allocates nothing per call.
 *
 * The chain: 7 revolute joints about their local z, joint i's frame placed by the
 * 4x4 `placements[i]` in its parent's (after the parent's rotation), the TCP by
 * `tool` in joint 7's frame: T_i = T_{i-1} P_i Rz(q_i), TCP = T_7 F.
 */
#define PY_SSIZE_T_CLEAN
#define _GNU_SOURCE
#include <Python.h>
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define N 7

typedef struct {
    double r[9]; /* row-major rotation */
    double p[3];
} frame;

static int get_buffer(PyObject *obj, Py_buffer *view, Py_ssize_t count, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    if (view->itemsize != 8 || (view->format && strcmp(view->format, "d") != 0) ||
        view->len != count * 8) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd float64 values in a C-contiguous array",
                     name, count);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* One float64 array argument of a kernel call: how many values, writable or not, and
 * its name for the error. */
typedef struct {
    PyObject *obj;
    Py_ssize_t count;
    int writable;
    const char *name;
} array_arg;

/* Take the buffers of `n` array arguments, all or none: on the first that is refused the
 * ones already taken are released and the error stays set (-1). */
static int get_buffers(const array_arg *args, Py_buffer *views, int n)
{
    for (int i = 0; i < n; i++)
        if (get_buffer(args[i].obj, &views[i], args[i].count, args[i].writable, args[i].name) < 0) {
            while (i-- > 0)
                PyBuffer_Release(&views[i]);
            return -1;
        }
    return 0;
}

static void release_buffers(Py_buffer *views, int n)
{
    for (int i = 0; i < n; i++)
        PyBuffer_Release(&views[i]);
}

static void frame_from4x4(const double *m, frame *f)
{
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            f->r[3 * i + j] = m[4 * i + j];
        f->p[i] = m[4 * i + 3];
    }
}

static void compose(const frame *a, const frame *b, frame *out)
{
    frame o;
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            o.r[3 * i + j] = a->r[3 * i] * b->r[j] + a->r[3 * i + 1] * b->r[3 + j] +
                             a->r[3 * i + 2] * b->r[6 + j];
        o.p[i] = a->r[3 * i] * b->p[0] + a->r[3 * i + 1] * b->p[1] + a->r[3 * i + 2] * b->p[2] +
                 a->p[i];
    }
    *out = o;
}

static void rotate_z(frame *f, double q)
{
    /* f <- f Rz(q): columns 0 and 1 mix */
    double c = cos(q), s = sin(q);
    for (int i = 0; i < 3; i++) {
        double x = f->r[3 * i], y = f->r[3 * i + 1];
        f->r[3 * i] = c * x + s * y;
        f->r[3 * i + 1] = -s * x + c * y;
    }
}

/* forward kinematics: the joint frames (after their rotation) and the TCP */
static void chain(const double *placements, const double *tool, const double *q, frame joints[N],
                  frame *tcp)
{
    frame t = {{1, 0, 0, 0, 1, 0, 0, 0, 1}, {0, 0, 0}};
    for (int i = 0; i < N; i++) {
        frame p;
        frame_from4x4(placements + 16 * i, &p);
        compose(&t, &p, &t);
        rotate_z(&t, q[i]);
        joints[i] = t;
    }
    frame f;
    frame_from4x4(tool, &f);
    compose(&t, &f, tcp);
}

/* 6x7 Jacobian at the TCP, base-aligned: rows vx vy vz wx wy wz */
static void jacobian(const frame joints[N], const frame *tcp, double jac[6 * N])
{
    for (int i = 0; i < N; i++) {
        const double *r = joints[i].r;
        double z[3] = {r[2], r[5], r[8]};
        double d[3] = {tcp->p[0] - joints[i].p[0], tcp->p[1] - joints[i].p[1],
                       tcp->p[2] - joints[i].p[2]};
        jac[0 * N + i] = z[1] * d[2] - z[2] * d[1];
        jac[1 * N + i] = z[2] * d[0] - z[0] * d[2];
        jac[2 * N + i] = z[0] * d[1] - z[1] * d[0];
        jac[3 * N + i] = z[0];
        jac[4 * N + i] = z[1];
        jac[5 * N + i] = z[2];
    }
}

/* the rotation vector of a rotation matrix (as pinocchio's log3) */
static void log3(const double *r, double w[3])
{
    double tr = r[0] + r[4] + r[8];
    double cosine = (tr - 1.0) / 2.0;
    if (cosine > 1.0)
        cosine = 1.0;
    if (cosine < -1.0)
        cosine = -1.0;
    double angle = acos(cosine);
    double v[3] = {r[7] - r[5], r[2] - r[6], r[3] - r[1]};
    if (angle < 1e-6) { /* first order: R - R^T = 2 [w]x */
        w[0] = 0.5 * v[0];
        w[1] = 0.5 * v[1];
        w[2] = 0.5 * v[2];
        return;
    }
    if (M_PI - angle > 1e-4) {
        double k = angle / (2.0 * sin(angle));
        w[0] = k * v[0];
        w[1] = k * v[1];
        w[2] = k * v[2];
        return;
    }
    /* near pi: the axis from the diagonal (R = 2 n n^T - I), its sign from v */
    double n[3];
    for (int i = 0; i < 3; i++) {
        double x = (r[4 * i] + 1.0) / 2.0;
        n[i] = x > 0.0 ? sqrt(x) : 0.0;
    }
    if (n[0] >= n[1] && n[0] >= n[2]) {
        n[1] = copysign(n[1], r[1] + r[3]);
        n[2] = copysign(n[2], r[2] + r[6]);
        if (v[0] < 0) { n[0] = -n[0]; n[1] = -n[1]; n[2] = -n[2]; }
    } else if (n[1] >= n[2]) {
        n[0] = copysign(n[0], r[1] + r[3]);
        n[2] = copysign(n[2], r[5] + r[7]);
        if (v[1] < 0) { n[0] = -n[0]; n[1] = -n[1]; n[2] = -n[2]; }
    } else {
        n[0] = copysign(n[0], r[2] + r[6]);
        n[1] = copysign(n[1], r[5] + r[7]);
        if (v[2] < 0) { n[0] = -n[0]; n[1] = -n[1]; n[2] = -n[2]; }
    }
    double norm = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int i = 0; i < 3; i++)
        w[i] = angle * n[i] / (norm > 0 ? norm : 1.0);
}

/* solve the 6x6 symmetric positive definite system a x = b (Cholesky); 0 on success */
static int cholesky_solve(double a[36], double b[6])
{
    for (int j = 0; j < 6; j++) {
        double d = a[6 * j + j];
        for (int k = 0; k < j; k++)
            d -= a[6 * j + k] * a[6 * j + k];
        if (!(d > 0.0))
            return -1;
        d = sqrt(d);
        a[6 * j + j] = d;
        for (int i = j + 1; i < 6; i++) {
            double s = a[6 * i + j];
            for (int k = 0; k < j; k++)
                s -= a[6 * i + k] * a[6 * j + k];
            a[6 * i + j] = s / d;
        }
    }
    for (int i = 0; i < 6; i++) { /* L y = b */
        double s = b[i];
        for (int k = 0; k < i; k++)
            s -= a[6 * i + k] * b[k];
        b[i] = s / a[6 * i + i];
    }
    for (int i = 5; i >= 0; i--) { /* L^T x = y */
        double s = b[i];
        for (int k = i + 1; k < 6; k++)
            s -= a[6 * k + i] * b[k];
        b[i] = s / a[6 * i + i];
    }
    return 0;
}

static void frame_to4x4(const frame *f, double *m)
{
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            m[4 * i + j] = f->r[3 * i + j];
        m[4 * i + 3] = f->p[i];
    }
    m[12] = m[13] = m[14] = 0.0;
    m[15] = 1.0;
}

/* jacobian(placements, tool, q, pose_out[16], jac_out[42]) */
static PyObject *py_jacobian(PyObject *self, PyObject *args)
{
    PyObject *po, *to, *qo, *oo, *jo;
    if (!PyArg_ParseTuple(args, "OOOOO", &po, &to, &qo, &oo, &jo))
        return NULL;
    Py_buffer b[5];
    const array_arg in[5] = {{po, N * 16, 0, "placements"}, {to, 16, 0, "tool"}, {qo, N, 0, "q"},
                             {oo, 16, 1, "pose"}, {jo, 6 * N, 1, "jacobian"}};
    if (get_buffers(in, b, 5) < 0)
        return NULL;
    const double *placements = b[0].buf, *tool = b[1].buf, *q = b[2].buf;
    frame joints[N], tcp;
    chain(placements, tool, q, joints, &tcp);
    frame_to4x4(&tcp, b[3].buf);
    jacobian(joints, &tcp, b[4].buf);
    release_buffers(b, 5);
    Py_RETURN_NONE;
}

/* joint_points(placements, tool, flange, q, out[30]): the base, the seven joint frames'
 * origins, the flange (`flange` in joint 7's frame) and the TCP, as 10 rows of xyz:
 * Kinematics.joint_origins in one call (the capsules of speed and separation
 * monitoring, every cycle a person is near). */
#define POINTS 10

/* Base, the seven joint origins, the flange and the TCP (POINTS x 3) into out. */
static void points_of(const double *placements, const double *tool, const double *flange_in_7,
                      const double *q, double *out)
{
    frame joints[N], tcp, flange, at;
    chain(placements, tool, q, joints, &tcp);
    frame_from4x4(flange_in_7, &flange);
    compose(&joints[N - 1], &flange, &at);
    out[0] = out[1] = out[2] = 0.0;
    for (int i = 0; i < N; i++)
        memcpy(out + 3 * (i + 1), joints[i].p, 3 * sizeof(double));
    memcpy(out + 24, at.p, 3 * sizeof(double));
    memcpy(out + 27, tcp.p, 3 * sizeof(double));
}

static PyObject *py_joint_points(PyObject *self, PyObject *args)
{
    PyObject *po, *to, *fo, *qo, *oo;
    if (!PyArg_ParseTuple(args, "OOOOO", &po, &to, &fo, &qo, &oo))
        return NULL;
    Py_buffer b[5];
    const array_arg in[5] = {{po, N * 16, 0, "placements"}, {to, 16, 0, "tool"},
                             {fo, 16, 0, "flange"}, {qo, N, 0, "q"}, {oo, 30, 1, "out"}};
    if (get_buffers(in, b, 5) < 0)
        return NULL;
    points_of(b[0].buf, b[1].buf, b[2].buf, b[3].buf, b[4].buf);
    release_buffers(b, 5);
    Py_RETURN_NONE;
}

/* ik_step(placements, tool, q[7], target[16], rest[7], lower[7], upper[7],
 *         max_step[7], out[7], damping2, rest_gain_dt) -> bool (False: not solved)
 * dq = J^T (J J^T + d^2 I)^-1 (err - J r) + r, r = rest_gain dt (rest - q);
 * scaled so no joint exceeds its max step; q + dq clamped to [lower, upper]. */
static PyObject *py_ik_step(PyObject *self, PyObject *args)
{
    PyObject *obj[9];
    double damping2, rest_gain_dt;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOdd", &obj[0], &obj[1], &obj[2], &obj[3], &obj[4],
                          &obj[5], &obj[6], &obj[7], &obj[8], &damping2, &rest_gain_dt))
        return NULL;
    const array_arg in[9] = {{obj[0], N * 16, 0, "placements"}, {obj[1], 16, 0, "tool"},
                             {obj[2], N, 0, "q"},          {obj[3], 16, 0, "target"},
                             {obj[4], N, 0, "rest"},       {obj[5], N, 0, "lower"},
                             {obj[6], N, 0, "upper"},      {obj[7], N, 0, "max_step"},
                             {obj[8], N, 1, "out"}};
    Py_buffer b[9];
    if (get_buffers(in, b, 9) < 0)
        return NULL;
    const double *q = b[2].buf, *target = b[3].buf, *rest = b[4].buf, *lower = b[5].buf,
                 *upper = b[6].buf, *max_step = b[7].buf;
    double *out = b[8].buf;
    frame joints[N], tcp, goal;
    chain(b[0].buf, b[1].buf, q, joints, &tcp);
    double jac[6 * N];
    jacobian(joints, &tcp, jac);
    frame_from4x4(target, &goal);
    double err[6];
    for (int i = 0; i < 3; i++)
        err[i] = goal.p[i] - tcp.p[i];
    double rel[9]; /* goal R tcp R^T */
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            rel[3 * i + j] = goal.r[3 * i] * tcp.r[3 * j] + goal.r[3 * i + 1] * tcp.r[3 * j + 1] +
                             goal.r[3 * i + 2] * tcp.r[3 * j + 2];
    log3(rel, err + 3);
    double r[N], rhs[6], a[36];
    for (int i = 0; i < N; i++)
        r[i] = rest_gain_dt * (rest[i] - q[i]);
    for (int i = 0; i < 6; i++) {
        double s = 0.0;
        for (int k = 0; k < N; k++)
            s += jac[i * N + k] * r[k];
        rhs[i] = err[i] - s;
        for (int j = 0; j < 6; j++) {
            double t = 0.0;
            for (int k = 0; k < N; k++)
                t += jac[i * N + k] * jac[j * N + k];
            a[6 * i + j] = t + (i == j ? damping2 : 0.0);
        }
    }
    int ok = cholesky_solve(a, rhs) == 0;
    double dq[N], scale = 0.0;
    for (int k = 0; k < N; k++) {
        double s = r[k];
        for (int i = 0; i < 6; i++)
            s += jac[i * N + k] * rhs[i];
        dq[k] = ok ? s : 0.0;
        double x = fabs(dq[k]) / max_step[k];
        if (x > scale)
            scale = x;
    }
    for (int k = 0; k < N; k++) {
        double v = q[k] + (scale > 1.0 ? dq[k] / scale : dq[k]);
        out[k] = v < lower[k] ? lower[k] : (v > upper[k] ? upper[k] : v);
        if (!isfinite(out[k]))
            ok = 0;
    }
    release_buffers(b, 9);
    return PyBool_FromLong(ok);
}

static double clamp01(double x) { return x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x); }

/* segment-segment distance, as components/domain/distance.py computes it */
static double segment_distance(const double *p1, const double *q1, const double *p2,
                               const double *q2)
{
    const double EPS = 1e-12, PARALLEL = 1e-14;
    double d1[3], d2[3], rr[3];
    for (int i = 0; i < 3; i++) {
        d1[i] = q1[i] - p1[i];
        d2[i] = q2[i] - p2[i];
        rr[i] = p1[i] - p2[i];
    }
    double a = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2];
    double e = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2];
    double b = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2];
    double c = d1[0] * rr[0] + d1[1] * rr[1] + d1[2] * rr[2];
    double f = d2[0] * rr[0] + d2[1] * rr[1] + d2[2] * rr[2];
    double ae = a * e, denom = ae - b * b, s, t;
    int first_point = a <= EPS, second_point = e <= EPS;
    double on_first = first_point ? 0.0 : clamp01(-c / a);
    if (second_point) {
        s = on_first;
        t = 0.0;
    } else {
        s = denom > PARALLEL * ae ? clamp01((b * f - c * e) / denom) : 0.0;
        t = (b * s + f) / e;
    }
    if (t < 0.0)
        s = on_first;
    else if (t > 1.0)
        s = first_point ? 0.0 : clamp01((b - c) / a);
    if (first_point)
        s = 0.0;
    t = clamp01(t);
    double sum = 0.0;
    for (int i = 0; i < 3; i++) {
        double x = rr[i] + s * d1[i] - t * d2[i];
        sum += x * x;
    }
    return sqrt(sum);
}

/* The least surface distance between capsules (a1, b1, r1)[n] and (a2, b2, r2)[m]: inf
 * if either set is empty, NaN as soon as a pair's is (as numpy's min: never a clear
 * verdict); the pair in *bi, *bj (-1 if none). */
static double capsule_least(const double *a1, const double *b1, const double *r1, Py_ssize_t n,
                            const double *a2, const double *b2, const double *r2, Py_ssize_t m,
                            Py_ssize_t *bi, Py_ssize_t *bj)
{
    double best = INFINITY;
    *bi = *bj = -1;
    for (Py_ssize_t i = 0; i < n; i++)
        for (Py_ssize_t j = 0; j < m; j++) {
            double d = segment_distance(a1 + 3 * i, b1 + 3 * i, a2 + 3 * j, b2 + 3 * j) - r1[i] -
                       r2[j];
            if (d < best || d != d) {
                best = d;
                *bi = i;
                *bj = j;
                if (d != d)
                    return best;
            }
        }
    return best;
}

/* Take the float64 buffers of capsule sets: (a, b, r) triples whose a and b hold 3 values
 * per radius; their counts in counts[]. All or none, as get_buffers. */
static int get_capsule_buffers(PyObject *const *obj, Py_buffer *b, int sets, Py_ssize_t *counts)
{
    int got = 0;
    for (; got < 3 * sets; got++)
        if (PyObject_GetBuffer(obj[got], &b[got], PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            break;
    int bad = got < 3 * sets;
    for (int i = 0; i < got && !bad; i++)
        if (b[i].itemsize != 8 || (b[i].format && strcmp(b[i].format, "d") != 0))
            bad = 2;
    for (int k = 0; k < sets && !bad; k++) {
        counts[k] = b[3 * k + 2].len / 8;
        if (b[3 * k].len != 24 * counts[k] || b[3 * k + 1].len != 24 * counts[k])
            bad = 2;
    }
    if (bad) {
        for (int i = 0; i < got; i++)
            PyBuffer_Release(&b[i]);
        if (bad == 2)
            PyErr_SetString(PyExc_ValueError, "capsules: (n, 3), (n, 3), (n,) float64 arrays");
        return -1;
    }
    return 0;
}

/* capsule_min(a1[n*3], b1[n*3], r1[n], a2[m*3], b2[m*3], r2[m]) -> (min, i, j) */
static PyObject *py_capsule_min(PyObject *self, PyObject *args)
{
    PyObject *obj[6];
    if (!PyArg_ParseTuple(args, "OOOOOO", &obj[0], &obj[1], &obj[2], &obj[3], &obj[4], &obj[5]))
        return NULL;
    Py_buffer b[6];
    Py_ssize_t count[2], bi, bj;
    if (get_capsule_buffers(obj, b, 2, count) < 0)
        return NULL;
    double best = capsule_least(b[0].buf, b[1].buf, b[2].buf, count[0], b[3].buf, b[4].buf,
                                b[5].buf, count[1], &bi, &bj);
    release_buffers(b, 6);
    return Py_BuildValue("(dnn)", best, bi, bj);
}

/* Speed and separation monitoring (components/domain/separation.py, SeparationMonitor):
 * the same formulas, in the same order, with Python's min() and max() (the first argument
 * unless the second compares beyond it, so a NaN stays where Python keeps it). */
static double py_min(double a, double b) { return b < a ? b : a; }
static double py_max(double a, double b) { return b > a ? b : a; }

/* The SSM terms, in the order SeparationMonitor packs them. */
enum {
    V_H, REACTION, ENGAGE, DECEL, INTRUSION, Z_D, Z_R, SLOW_BAND, MAX_SPEED, WINDOW,
    FASTEST_LINK, MAX_QUIET, TERMS
};

static double protective_distance(const double *p, double v, double age)
{
    double t_r = py_max(age, 0.0) + p[REACTION];
    return p[V_H] * (t_r + (p[ENGAGE] + v / p[DECEL])) + v * t_r +
           (v * p[ENGAGE] + v * v / (2.0 * p[DECEL])) + p[INTRUSION] + p[Z_D] + p[Z_R];
}

static double allowed_speed(const double *p, double separation, double age)
{
    double a = 1.0 / (2.0 * p[DECEL]);
    double t_r = py_max(age, 0.0) + p[REACTION];
    double b = p[V_H] / p[DECEL] + t_r + p[ENGAGE];
    double c = protective_distance(p, 0.0, age) - separation;
    if (c >= 0.0)
        return 0.0;
    return (-b + sqrt(b * b - 4.0 * a * c)) / (2.0 * a);
}

/* The link capsules' ends of the last `WINDOW` seconds: a ring of `rows` rows, each the
 * time then the 6m coordinates (every a, then every b); meta = (count, first row). */
typedef struct {
    double *rows, *meta;
    Py_ssize_t capacity, width;
} speed_ring;

static double *ring_row(const speed_ring *h, Py_ssize_t k)
{
    return h->rows + ((Py_ssize_t)h->meta[1] + k) % h->capacity * h->width;
}

static void ring_drop_first(speed_ring *h)
{
    h->meta[1] = (double)(((Py_ssize_t)h->meta[1] + 1) % h->capacity);
    h->meta[0] -= 1.0;
}

/* SeparationMonitor.robot_speed: the fastest capsule end since the newest row at least
 * `window` old (0 on the first call, or when the clock stepped back before it), the
 * tool's (the last b) over the same span in *tcp; then the ends of `now` appended (the
 * oldest dropped if the ring is full). */
static double ring_speed(speed_ring *h, const double *a, const double *b, Py_ssize_t m, double now,
                         double window, double *tcp)
{
    while (h->meta[0] > 1.0 && now - ring_row(h, 1)[0] >= window)
        ring_drop_first(h);
    double speed = 0.0;
    *tcp = 0.0;
    if (h->meta[0] > 0.0 && now > ring_row(h, 0)[0]) {
        const double *before = ring_row(h, 0);
        double dt = now - before[0], fastest = -INFINITY, tip = 0.0;
        for (Py_ssize_t k = 0; k < 2 * m; k++) {
            const double *end = k < m ? a + 3 * k : b + 3 * (k - m);
            const double *then = before + 1 + 3 * k;
            double x = end[0] - then[0], y = end[1] - then[1], z = end[2] - then[2];
            double d = x * x + y * y + z * z;
            if (d > fastest || d != d)
                fastest = d;
            tip = d;
        }
        speed = sqrt(fastest) / dt;
        *tcp = sqrt(tip) / dt;
    }
    if ((Py_ssize_t)h->meta[0] == h->capacity)
        ring_drop_first(h);
    double *row = ring_row(h, (Py_ssize_t)h->meta[0]);
    row[0] = now;
    memcpy(row + 1, a, 3 * m * sizeof(double));
    memcpy(row + 1 + 3 * m, b, 3 * m * sizeof(double));
    h->meta[0] += 1.0;
    return speed;
}

/* The ring's buffers, checked against the robot's m capsules. */
static int get_ring(PyObject *rows_o, PyObject *meta_o, Py_ssize_t m, Py_buffer *views,
                    speed_ring *h)
{
    if (PyObject_GetBuffer(rows_o, &views[0], PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_WRITABLE) <
        0)
        return -1;
    if (get_buffer(meta_o, &views[1], 2, 1, "meta") < 0) {
        PyBuffer_Release(&views[0]);
        return -1;
    }
    h->rows = views[0].buf;
    h->meta = views[1].buf;
    h->width = 1 + 6 * m;
    h->capacity = views[0].len / 8 / h->width;
    if (views[0].itemsize != 8 || (views[0].format && strcmp(views[0].format, "d") != 0) ||
        views[0].len != 8 * h->width * h->capacity || h->capacity < 2 || h->meta[0] < 0.0 ||
        h->meta[0] > (double)h->capacity || h->meta[1] < 0.0 ||
        h->meta[1] >= (double)h->capacity) {
        PyErr_Format(PyExc_ValueError, "ring: rows of 1 + 6 x %zd float64 values (2 or more) "
                                       "and a (count, first) within them", m);
        release_buffers(views, 2);
        return -1;
    }
    return 0;
}

/* ssm_speed(a[m*3], b[m*3], rows, meta, now, window) -> (speed, tcp_speed) */
static PyObject *py_ssm_speed(PyObject *self, PyObject *args)
{
    PyObject *ao, *bo, *ro, *mo;
    double now, window, tcp;
    if (!PyArg_ParseTuple(args, "OOOOdd", &ao, &bo, &ro, &mo, &now, &window))
        return NULL;
    Py_buffer b[4];
    if (PyObject_GetBuffer(ao, &b[0], PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return NULL;
    Py_ssize_t m = b[0].len / 24;
    const array_arg ends = {bo, 3 * m, 0, "b"};
    if (b[0].itemsize != 8 || b[0].len != 24 * m ||
        (b[0].format && strcmp(b[0].format, "d") != 0)) {
        PyBuffer_Release(&b[0]);
        PyErr_SetString(PyExc_ValueError, "a: (m, 3) float64 values");
        return NULL;
    }
    if (get_buffers(&ends, &b[1], 1) < 0) {
        PyBuffer_Release(&b[0]);
        return NULL;
    }
    speed_ring h;
    if (get_ring(ro, mo, m, &b[2], &h) < 0) {
        release_buffers(b, 2);
        return NULL;
    }
    double speed = ring_speed(&h, b[0].buf, b[1].buf, m, now, window, &tcp);
    release_buffers(b, 4);
    return Py_BuildValue("(dd)", speed, tcp);
}

/* SeparationMonitor.quiet_cycles: the cycles of dt before a check can change anything. */
static long quiet_cycles(const double *p, double separation, double age, double dt)
{
    if (!isfinite(separation))
        return 0;
    double guard = py_max(protective_distance(p, p[FASTEST_LINK], age),
                          protective_distance(p, 0.0, age) + p[SLOW_BAND]);
    double margin = separation - guard;
    if (margin <= 0.0)
        return 0;
    double cycles = margin / ((2.0 * p[V_H] + p[FASTEST_LINK]) * dt);
    return cycles < p[MAX_QUIET] ? (long)cycles : (long)p[MAX_QUIET];
}

/* ssm_check(ra, rb, rr, pa, pb, pr, rows, meta, terms[TERMS], age, now, cap_age, dt)
 *   -> (separation, robot_speed, protective, cap, stop, tcp_speed, quiet):
 * SeparationMonitor.check for the robot's capsules (ra, rb, rr) and the people's (pa,
 * pb, pr; none: nobody), and its quiet_cycles for cycles of dt. */
static PyObject *py_ssm_check(PyObject *self, PyObject *args)
{
    PyObject *obj[6], *ro, *mo, *to;
    double age, now, cap_age, dt, tcp;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOdddd", &obj[0], &obj[1], &obj[2], &obj[3], &obj[4],
                          &obj[5], &ro, &mo, &to, &age, &now, &cap_age, &dt))
        return NULL;
    if (!(dt > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "ssm_check: a cycle (dt) must be > 0");
        return NULL;
    }
    Py_buffer b[9];
    Py_ssize_t count[2], bi, bj;
    if (get_capsule_buffers(obj, b, 2, count) < 0)
        return NULL;
    speed_ring h;
    if (get_ring(ro, mo, count[0], &b[6], &h) < 0) {
        release_buffers(b, 6);
        return NULL;
    }
    const array_arg terms = {to, TERMS, 0, "terms"};
    if (get_buffers(&terms, &b[8], 1) < 0) {
        release_buffers(b, 8);
        return NULL;
    }
    const double *p = b[8].buf;
    double speed = ring_speed(&h, b[0].buf, b[1].buf, count[0], now, p[WINDOW], &tcp);
    double separation = INFINITY, protective = 0.0, cap = INFINITY;
    int stop = 0;
    if (count[1] > 0) {
        separation = capsule_least(b[0].buf, b[1].buf, b[2].buf, count[0], b[3].buf, b[4].buf,
                                   b[5].buf, count[1], &bi, &bj);
        protective = protective_distance(p, speed, age);
        cap_age = py_max(age, cap_age);
        double standing = protective_distance(p, 0.0, cap_age);
        double share = p[SLOW_BAND] > 0.0 ? (separation - standing) / p[SLOW_BAND] : 1.0;
        cap = py_min(p[MAX_SPEED] * py_min(py_max(share, 0.0), 1.0),
                     allowed_speed(p, separation, cap_age));
        if (share >= 1.0 && cap >= p[MAX_SPEED])
            cap = INFINITY;
        stop = !(separation >= protective); /* a NaN separation is no clear verdict */
    }
    long quiet = quiet_cycles(p, separation, age, dt);
    release_buffers(b, 9);
    return Py_BuildValue("(ddddNdl)", separation, speed, protective, cap, PyBool_FromLong(stop),
                         tcp, quiet);
}

/* envelopes_decode(sample, prefix[8]) -> (publisher, seq, stamp, values, na, nb, nr, finite,
 *                                          radii_ok) or None if it is not a whole Envelopes
 * sample (framework/messages.py's layout: the 8-byte prefix of magic, version and type
 * id, publisher u64, seq u64, then stamp f64 and the arrays a, b, radius, each a u32
 * count and its f64s, little-endian, nothing after). `values` holds a, b and radius as
 * float64 bytes (a new object: the sample's own memory is not kept); `finite`: every
 * value and their sum finite, as the Python check; `radii_ok`: none negative. */
static PyObject *py_envelopes_decode(PyObject *self, PyObject *args)
{
    Py_buffer data, prefix;
    if (!PyArg_ParseTuple(args, "y*y*", &data, &prefix))
        return NULL;
    const unsigned char *p = data.buf;
    Py_ssize_t len = data.len, at = 32, count[3], start[3];
    PyObject *result = NULL;
    if (prefix.len != 8 || len < at || memcmp(p, prefix.buf, 8) != 0)
        goto none;
    for (int k = 0; k < 3; k++) {
        uint32_t n;
        if (at + 4 > len)
            goto none;
        memcpy(&n, p + at, 4);
        at += 4;
        if ((Py_ssize_t)n > (len - at) / 8)
            goto none;
        count[k] = n;
        start[k] = at;
        at += 8 * (Py_ssize_t)n;
    }
    if (at != len)
        goto none;
    uint64_t publisher, seq;
    double stamp;
    memcpy(&publisher, p + 8, 8);
    memcpy(&seq, p + 16, 8);
    memcpy(&stamp, p + 24, 8);
    Py_ssize_t total = count[0] + count[1] + count[2];
    PyObject *values = PyBytes_FromStringAndSize(NULL, 8 * total);
    if (values == NULL)
        goto done;
    double *out = (double *)PyBytes_AS_STRING(values), sum = 0.0;
    int finite = 1, radii_ok = 1;
    Py_ssize_t o = 0;
    for (int k = 0; k < 3; k++) {
        memcpy(out + o, p + start[k], 8 * count[k]);
        for (Py_ssize_t i = 0; i < count[k]; i++) {
            double v = out[o + i];
            sum += v;
            if (!isfinite(v))
                finite = 0;
            if (k == 2 && v < 0.0)
                radii_ok = 0;
        }
        o += count[k];
    }
    if (!isfinite(sum))
        finite = 0;
    result = Py_BuildValue("(KKdNnnnNN)", (unsigned long long)publisher, (unsigned long long)seq,
                           stamp, values, count[0], count[1], count[2], PyBool_FromLong(finite),
                           PyBool_FromLong(radii_ok));
    goto done;
none:
    result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&data);
    PyBuffer_Release(&prefix);
    return result;
}

/* the rotation matrix (row-major) of a rotation vector (Rodrigues) */
static void exp3(const double w[3], double r[9])
{
    double angle = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    double a, b; /* sin(t)/t, (1 - cos(t))/t^2, by their series near 0 */
    if (angle < 1e-4) {
        double t2 = angle * angle;
        a = 1.0 - t2 / 6.0;
        b = 0.5 - t2 / 24.0;
    } else {
        a = sin(angle) / angle;
        b = (1.0 - cos(angle)) / (angle * angle);
    }
    double x = w[0], y = w[1], z = w[2];
    r[0] = 1.0 - b * (y * y + z * z);
    r[1] = -a * z + b * x * y;
    r[2] = a * y + b * x * z;
    r[3] = a * z + b * x * y;
    r[4] = 1.0 - b * (x * x + z * z);
    r[5] = -a * x + b * y * z;
    r[6] = -a * y + b * x * z;
    r[7] = a * x + b * y * z;
    r[8] = 1.0 - b * (x * x + y * y);
}

static void mul3(const double *a, const double *b, double *out)
{
    double o[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            o[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
    memcpy(out, o, sizeof o);
}

/* path_pose(start[16], delta_p[3], delta_r[3], u, offset[6], out[16]): the pose u of
 * the way along the straight path (position linear, rotation start R exp(u delta_r)),
 * the steering offset added (translation, then rotation exp(offset_r) on the left) */
static PyObject *py_path_pose(PyObject *self, PyObject *args)
{
    PyObject *so, *po, *ro, *oo, *out_o;
    double u;
    if (!PyArg_ParseTuple(args, "OOOdOO", &so, &po, &ro, &u, &oo, &out_o))
        return NULL;
    Py_buffer b[5];
    const array_arg in[5] = {{so, 16, 0, "start"}, {po, 3, 0, "delta_p"}, {ro, 3, 0, "delta_r"},
                             {oo, 6, 0, "offset"}, {out_o, 16, 1, "out"}};
    if (get_buffers(in, b, 5) < 0)
        return NULL;
    const double *st = b[0].buf, *dp = b[1].buf, *dr = b[2].buf, *off = b[3].buf;
    double *out = b[4].buf;
    double w[3] = {u * dr[0], u * dr[1], u * dr[2]}, e[9], r0[9], r[9];
    exp3(w, e);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r0[3 * i + j] = st[4 * i + j];
    mul3(r0, e, r);
    if (off[3] != 0.0 || off[4] != 0.0 || off[5] != 0.0) {
        exp3(off + 3, e);
        mul3(e, r, r);
    }
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            out[4 * i + j] = r[3 * i + j];
        out[4 * i + 3] = st[4 * i + 3] + u * dp[i] + off[i];
    }
    out[12] = out[13] = out[14] = 0.0;
    out[15] = 1.0;
    release_buffers(b, 5);
    Py_RETURN_NONE;
}

/* seven floats from a tuple or list of numbers (ints and floats, as Python's
 * `isinstance(v, float | int)`): 0, 1 if it is not 7 finite numbers, -1 on a Python error */
static int seven(PyObject *obj, double out[N])
{
    PyObject *fast = PySequence_Fast(obj, "expected a sequence of 7 numbers");
    if (fast == NULL)
        return -1;
    int bad = PySequence_Fast_GET_SIZE(fast) != N;
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (int i = 0; !bad && i < N; i++) {
        PyObject *v = items[i];
        if (PyFloat_Check(v))
            out[i] = PyFloat_AS_DOUBLE(v);
        else if (PyLong_Check(v)) {
            out[i] = PyLong_AsDouble(v);
            if (out[i] == -1.0 && PyErr_Occurred()) { /* beyond a float: not finite */
                PyErr_Clear();
                bad = 1;
            }
        } else
            bad = 1;
        if (!bad && !isfinite(out[i]))
            bad = 1;
    }
    Py_DECREF(fast);
    return bad;
}

/* capsule_points(placements, tool, flange, q, pairs[2m], a_out[m*3], b_out[m*3]): the arm's
 * link capsules' ends for joints q (any sequence of 7 numbers): capsule k from point
 * pairs[2k] to point pairs[2k + 1] of joint_points (indices 0-9, as float64). */
static PyObject *py_capsule_points(PyObject *self, PyObject *args)
{
    PyObject *po, *to, *fo, *qo, *pairs_o, *ao, *bo;
    if (!PyArg_ParseTuple(args, "OOOOOOO", &po, &to, &fo, &qo, &pairs_o, &ao, &bo))
        return NULL;
    double q[N];
    int bad = seven(qo, q);
    if (bad < 0)
        return NULL;
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "capsule_points: q needs 7 finite numbers");
        return NULL;
    }
    Py_buffer pb;
    if (PyObject_GetBuffer(pairs_o, &pb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return NULL;
    Py_ssize_t m = pb.len / 16;
    int wrong = pb.itemsize != 8 || pb.len != 16 * m || (pb.format && strcmp(pb.format, "d") != 0);
    for (Py_ssize_t k = 0; !wrong && k < 2 * m; k++) {
        double index = ((const double *)pb.buf)[k];
        wrong = !(index >= 0.0 && index < POINTS) || index != (double)(int)index;
    }
    if (wrong) {
        PyBuffer_Release(&pb);
        PyErr_SetString(PyExc_ValueError, "capsule_points: pairs of point indices 0-9 (float64)");
        return NULL;
    }
    Py_buffer b[5];
    const array_arg in[5] = {{po, N * 16, 0, "placements"}, {to, 16, 0, "tool"},
                             {fo, 16, 0, "flange"}, {ao, 3 * m, 1, "a_out"},
                             {bo, 3 * m, 1, "b_out"}};
    if (get_buffers(in, b, 5) < 0) {
        PyBuffer_Release(&pb);
        return NULL;
    }
    double points[3 * POINTS], *a = b[3].buf, *out_b = b[4].buf;
    const double *pairs = pb.buf;
    points_of(b[0].buf, b[1].buf, b[2].buf, q, points);
    for (Py_ssize_t k = 0; k < m; k++) {
        memcpy(a + 3 * k, points + 3 * (int)pairs[2 * k], 3 * sizeof(double));
        memcpy(out_b + 3 * k, points + 3 * (int)pairs[2 * k + 1], 3 * sizeof(double));
    }
    release_buffers(b, 5);
    PyBuffer_Release(&pb);
    Py_RETURN_NONE;
}

/* servo_aim(values, reference, limit, aim, bound, reach, feed_forward, ctrl) -> joint
 * The simulated arm's setpoint guard and servo target (components/sim/arm.py,
 * SimulatedArm.command): -2 if `values` is not 7 finite numbers; else the first joint
 * of the largest |v - r| / (limit reach + 1e-6) above 1 (a step no arm can follow; ctrl
 * untouched), or -1 with ctrl[j] = clamp(v + aim + (v - r) feed_forward, +-bound), in
 * the same order of operations as the Python it replaces. */
static PyObject *py_servo_aim(PyObject *self, PyObject *args)
{
    PyObject *vo, *ro, *lo, *ao, *bo, *co;
    double reach, feed_forward;
    if (!PyArg_ParseTuple(args, "OOOOOddO", &vo, &ro, &lo, &ao, &bo, &reach, &feed_forward, &co))
        return NULL;
    double v[N], r[N], limit[N], aim[N], bound[N];
    int bad = seven(vo, v);
    if (bad < 0)
        return NULL;
    if (bad)
        return PyLong_FromLong(-2);
    PyObject *rest[4] = {ro, lo, ao, bo};
    double *into[4] = {r, limit, aim, bound};
    for (int k = 0; k < 4; k++) {
        int wrong = seven(rest[k], into[k]);
        if (wrong < 0)
            return NULL;
        if (wrong) {
            PyErr_SetString(PyExc_ValueError, "servo_aim: reference, limits, aim and bounds need 7 finite numbers");
            return NULL;
        }
    }
    Py_buffer cb;
    if (get_buffer(co, &cb, N, 1, "ctrl") < 0)
        return NULL;
    double worst = 1.0, target[N];
    int joint = -1;
    for (int j = 0; j < N; j++) {
        double delta = v[j] - r[j];
        double ratio = fabs(delta) / (limit[j] * reach + 1e-6);
        if (ratio > worst) {
            worst = ratio;
            joint = j;
        }
        double t = v[j] + aim[j] + delta * feed_forward;
        target[j] = t < -bound[j] ? -bound[j] : (t > bound[j] ? bound[j] : t);
    }
    if (joint < 0)
        memcpy(cb.buf, target, sizeof target);
    PyBuffer_Release(&cb);
    return PyLong_FromLong(joint);
}

/* steer_step(wanted[6], offset[6], budget, radius) -> size: the interpolator's steering
 * correction (components/robot/interpolator.py, InterpolatorCore._correct): error =
 * wanted - offset, its size max(|e_t|, |e_r| radius); offset moves by error min(1,
 * budget / size) in place (nothing if size is 0). Returns the size before the move. */
static PyObject *py_steer_step(PyObject *self, PyObject *args)
{
    PyObject *wo, *oo;
    double budget, radius;
    if (!PyArg_ParseTuple(args, "OOdd", &wo, &oo, &budget, &radius))
        return NULL;
    Py_buffer b[2];
    const array_arg in[2] = {{wo, 6, 0, "wanted"}, {oo, 6, 1, "offset"}};
    if (get_buffers(in, b, 2) < 0)
        return NULL;
    const double *w = b[0].buf;
    double *o = b[1].buf, e[6];
    for (int i = 0; i < 6; i++)
        e[i] = w[i] - o[i];
    double t = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
    double r = sqrt(e[3] * e[3] + e[4] * e[4] + e[5] * e[5]) * radius;
    double size = t > r ? t : r;
    if (size > 0.0) {
        double share = budget / size;
        if (share > 1.0)
            share = 1.0;
        for (int i = 0; i < 6; i++)
            o[i] = o[i] + e[i] * share;
    }
    release_buffers(b, 2);
    return PyFloat_FromDouble(size);
}

/* -- FRI 1.x datagrams (components/domain/fri.py is the reference: same fields, same
 * float32 rounding through Python's own PyFloat_Pack4/Unpack4) -------------------- */
#define FRI_MSR_SIZE 916
#define FRI_MSR_ID 0x2006
#define FRI_CMD_SIZE 376
#define FRI_CMD_ID 0x1005

static unsigned rd16(const unsigned char *p) { return (unsigned)p[0] | ((unsigned)p[1] << 8); }
static long rd32(const unsigned char *p)
{
    unsigned long u = (unsigned long)p[0] | ((unsigned long)p[1] << 8) |
                      ((unsigned long)p[2] << 16) | ((unsigned long)p[3] << 24);
    return (long)(int)(unsigned)u; /* int32 */
}
static unsigned long rdu32(const unsigned char *p)
{
    return (unsigned long)p[0] | ((unsigned long)p[1] << 8) | ((unsigned long)p[2] << 16) |
           ((unsigned long)p[3] << 24);
}
static void wr16(unsigned char *p, unsigned v)
{
    p[0] = v & 0xFF;
    p[1] = (v >> 8) & 0xFF;
}
static void wr32(unsigned char *p, unsigned long v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (v >> (8 * i)) & 0xFF;
}

static PyObject *floats7(const unsigned char *p)
{
    PyObject *t = PyTuple_New(N);
    if (t == NULL)
        return NULL;
    for (int i = 0; i < N; i++) {
        double v = PyFloat_Unpack4((const char *)p + 4 * i, 1);
        if (v == -1.0 && PyErr_Occurred()) {
            Py_DECREF(t);
            return NULL;
        }
        PyObject *f = PyFloat_FromDouble(v);
        if (f == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, i, f);
    }
    return t;
}

static double f32(const unsigned char *p) { return PyFloat_Unpack4((const char *)p, 1); }

/* fri_measurement(datagram) -> the fields of fri.Measurement in its order, or None if
 * it is no measurement (size, declared size or id): the caller asks the reference why */
static PyObject *py_fri_measurement(PyObject *self, PyObject *arg)
{
    Py_buffer b;
    if (PyObject_GetBuffer(arg, &b, PyBUF_SIMPLE) < 0)
        return NULL;
    const unsigned char *d = b.buf;
    if (b.len != FRI_MSR_SIZE || rd16(d + 4) != FRI_MSR_SIZE || rd16(d + 6) != FRI_MSR_ID) {
        PyBuffer_Release(&b);
        Py_RETURN_NONE;
    }
    PyObject *pos = floats7(d + 216), *cmd = floats7(d + 292), *off = floats7(d + 320),
             *trq = floats7(d + 444);
    PyObject *out = NULL;
    if (pos && cmd && off && trq && !PyErr_Occurred())
        out = Py_BuildValue("(IIdIIddddkINNNNlllNN)", rd16(d), rd16(d + 2), f32(d + 140),
                            rd16(d + 144), rd16(d + 146), f32(d + 160), f32(d + 164),
                            f32(d + 168), f32(d + 172), rdu32(d + 176), rd16(d + 182), pos,
                            cmd, off, trq, rd32(d + 72), rd32(d + 76), rd32(d + 80),
                            PyBool_FromLong(d[136] & 1), PyBool_FromLong(d[136] & 2));
    if (out == NULL) {
        Py_XDECREF(pos);
        Py_XDECREF(cmd);
        Py_XDECREF(off);
        Py_XDECREF(trq);
    }
    PyBuffer_Release(&b);
    return out;
}

/* fri_command(datagram) -> the fields of fri.Command in its order, or None if it is no
 * command (the caller asks the reference why) */
static PyObject *py_fri_command(PyObject *self, PyObject *arg)
{
    Py_buffer b;
    if (PyObject_GetBuffer(arg, &b, PyBUF_SIMPLE) < 0)
        return NULL;
    const unsigned char *d = b.buf;
    if (b.len != FRI_CMD_SIZE || rd16(d + 4) != FRI_CMD_SIZE || rd16(d + 6) != FRI_CMD_ID) {
        PyBuffer_Release(&b);
        Py_RETURN_NONE;
    }
    PyObject *pos = floats7(d + 144);
    PyObject *out = pos == NULL ? NULL
                                : Py_BuildValue("(IIkNll)", rd16(d), rd16(d + 2), rdu32(d + 140),
                                                pos, rd32(d + 72), rd32(d + 76));
    PyBuffer_Release(&b);
    return out;
}

/* fri_encode_command(send_seq, refl_seq, jnt_pos, request_number, request, flags) -> bytes:
 * fri.encode_command's datagram (every other byte zero) */
static PyObject *py_fri_encode_command(PyObject *self, PyObject *args)
{
    unsigned long long send_seq, refl_seq, flags;
    long long number, request;
    PyObject *jo;
    if (!PyArg_ParseTuple(args, "KKOLLK", &send_seq, &refl_seq, &jo, &number, &request, &flags))
        return NULL;
    if (number < INT32_MIN || number > INT32_MAX || request < INT32_MIN || request > INT32_MAX ||
        flags > 0xFFFFFFFFULL) {
        PyErr_SetString(PyExc_OverflowError, "fri_encode_command: a field beyond its width");
        return NULL;
    }
    PyObject *fast = PySequence_Fast(jo, "jnt_pos: a sequence of 7 numbers");
    if (fast == NULL)
        return NULL;
    if (PySequence_Fast_GET_SIZE(fast) != N) {
        Py_DECREF(fast);
        PyErr_SetString(PyExc_ValueError, "jnt_pos: 7 numbers");
        return NULL;
    }
    PyObject *out = PyBytes_FromStringAndSize(NULL, FRI_CMD_SIZE);
    if (out == NULL) {
        Py_DECREF(fast);
        return NULL;
    }
    unsigned char *d = (unsigned char *)PyBytes_AS_STRING(out);
    memset(d, 0, FRI_CMD_SIZE);
    wr16(d, (unsigned)(send_seq & 0xFFFF));
    wr16(d + 2, (unsigned)(refl_seq & 0xFFFF));
    wr16(d + 4, FRI_CMD_SIZE);
    wr16(d + 6, FRI_CMD_ID);
    wr32(d + 72, (unsigned long)(unsigned)(int)number);
    wr32(d + 76, (unsigned long)(unsigned)(int)request);
    wr32(d + 140, (unsigned long)flags);
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (int i = 0; i < N; i++) {
        double v = PyFloat_AsDouble(items[i]);
        if ((v == -1.0 && PyErr_Occurred()) || PyFloat_Pack4(v, (char *)d + 144 + 4 * i, 1) < 0) {
            Py_DECREF(fast);
            Py_DECREF(out);
            return NULL;
        }
    }
    Py_DECREF(fast);
    return out;
}

static int pack_floats(PyObject *seq, unsigned char *at, int count, const char *name)
{
    PyObject *fast = PySequence_Fast(seq, name);
    if (fast == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(fast) != count) {
        Py_DECREF(fast);
        PyErr_Format(PyExc_ValueError, "%s: %d numbers", name, count);
        return -1;
    }
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (int i = 0; i < count; i++) {
        double v = PyFloat_AsDouble(items[i]);
        if ((v == -1.0 && PyErr_Occurred()) || PyFloat_Pack4(v, (char *)at + 4 * i, 1) < 0) {
            Py_DECREF(fast);
            return -1;
        }
    }
    Py_DECREF(fast);
    return 0;
}

static int pack_f32(double v, unsigned char *at) { return PyFloat_Pack4(v, (char *)at, 1); }

static int fits(long long v, long long lo, long long hi, const char *name)
{
    if (v < lo || v > hi) {
        PyErr_Format(PyExc_OverflowError, "fri_encode_measurement: %s beyond its width", name);
        return 0;
    }
    return 1;
}

/* fri_encode_measurement(send_seq, refl_seq, timestamp, state, quality, stats, control,
 *   msr_jnt_pos, cmd_jnt_pos, cmd_jnt_pos_fri_offset|None, msr_jnt_trq|None, served,
 *   reason, cycle, braked, latched, sample_time) -> bytes: fri.encode_measurement's */
static PyObject *py_fri_encode_measurement(PyObject *self, PyObject *args)
{
    unsigned long long send_seq, refl_seq;
    double timestamp, sample_time;
    long long state, quality, control, served, reason, cycle;
    int braked, latched;
    PyObject *stats, *msr, *cmd, *off, *trq;
    if (!PyArg_ParseTuple(args, "KKdLLOLOOOOLLLppd", &send_seq, &refl_seq, &timestamp, &state,
                          &quality, &stats, &control, &msr, &cmd, &off, &trq, &served, &reason,
                          &cycle, &braked, &latched, &sample_time))
        return NULL;
    double rate, latency, jitter, miss_rate;
    long long misses;
    if (!PyArg_ParseTuple(stats, "ddddL;stats: answerRate, latency, jitter, missRate, missCounter",
                          &rate, &latency, &jitter, &miss_rate, &misses))
        return NULL;
    if (!fits(state, 0, 0xFFFF, "state") || !fits(quality, 0, 0xFFFF, "quality") ||
        !fits(control, 0, 0xFFFF, "control") || !fits(misses, 0, 0xFFFFFFFFLL, "missCounter") ||
        !fits(served, INT32_MIN, INT32_MAX, "served") || !fits(reason, INT32_MIN, INT32_MAX, "reason"))
        return NULL;
    PyObject *out = PyBytes_FromStringAndSize(NULL, FRI_MSR_SIZE);
    if (out == NULL)
        return NULL;
    unsigned char *d = (unsigned char *)PyBytes_AS_STRING(out);
    memset(d, 0, FRI_MSR_SIZE);
    wr16(d, (unsigned)(send_seq & 0xFFFF));
    wr16(d + 2, (unsigned)(refl_seq & 0xFFFF));
    wr16(d + 4, FRI_MSR_SIZE);
    wr16(d + 6, FRI_MSR_ID);
    wr32(d + 72, (unsigned long)(unsigned)(int)served);
    wr32(d + 76, (unsigned long)(unsigned)(int)reason);
    wr32(d + 80, (unsigned long)(cycle & 0x7FFFFFFF));
    wr16(d + 136, (braked ? 1 : 0) | (latched ? 2 : 0));
    wr16(d + 144, (unsigned)state);
    wr16(d + 146, (unsigned)quality);
    wr32(d + 176, (unsigned long)misses);
    wr16(d + 180, braked ? 0 : 1); /* power: the drives are on while released */
    wr16(d + 182, (unsigned)control);
    if (pack_f32(timestamp, d + 140) < 0 || pack_f32(sample_time, d + 148) < 0 ||
        pack_f32(sample_time, d + 152) < 0 || pack_f32(rate, d + 160) < 0 ||
        pack_f32(latency, d + 164) < 0 || pack_f32(jitter, d + 168) < 0 ||
        pack_f32(miss_rate, d + 172) < 0)
        goto fail;
    for (int i = 0; i < N; i++)
        if (pack_f32(30.0, d + 188 + 4 * i) < 0) /* temperatures */
            goto fail;
    if (pack_floats(msr, d + 216, N, "msr_jnt_pos") < 0 || pack_floats(cmd, d + 292, N, "cmd_jnt_pos") < 0)
        goto fail;
    if (off != Py_None && pack_floats(off, d + 320, N, "cmd_jnt_pos_fri_offset") < 0)
        goto fail;
    if (trq != Py_None && pack_floats(trq, d + 444, N, "msr_jnt_trq") < 0)
        goto fail;
    return out;
fail:
    Py_DECREF(out);
    return NULL;
}

/* seven numbers of a float64 array or of a sequence of numbers, NaNs and infinities as
 * they are: 0, 1 if it is not seven numbers, -1 on a Python error */
static int numbers7(PyObject *obj, double out[N])
{
    if (PyObject_CheckBuffer(obj)) {
        Py_buffer view;
        if (PyObject_GetBuffer(obj, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            return -1;
        int ok = view.itemsize == 8 && view.format && strcmp(view.format, "d") == 0 &&
                 view.len == N * 8;
        if (ok)
            memcpy(out, view.buf, N * sizeof(double));
        PyBuffer_Release(&view);
        if (ok)
            return 0;
    }
    PyObject *fast = PySequence_Fast(obj, "expected a sequence of 7 numbers");
    if (fast == NULL)
        return -1;
    int bad = PySequence_Fast_GET_SIZE(fast) != N;
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (int i = 0; !bad && i < N; i++) {
        out[i] = PyFloat_AsDouble(items[i]);
        if (out[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(fast);
            return -1;
        }
    }
    Py_DECREF(fast);
    return bad;
}

/* max_abs_diff(a, b) -> max |a_i - b_i| over 7 joints, as Python's max() over them
 * takes it (the first, then any larger: a NaN first stays, a NaN later is skipped) */
static PyObject *py_max_abs_diff(PyObject *self, PyObject *args)
{
    PyObject *ao, *bo;
    if (!PyArg_ParseTuple(args, "OO", &ao, &bo))
        return NULL;
    double a[N], b[N];
    int bad = numbers7(ao, a);
    if (bad == 0)
        bad = numbers7(bo, b);
    if (bad < 0)
        return NULL;
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "max_abs_diff: two sequences of 7 numbers");
        return NULL;
    }
    double worst = fabs(a[0] - b[0]);
    for (int i = 1; i < N; i++) {
        double d = fabs(a[i] - b[i]);
        if (d > worst)
            worst = d;
    }
    return PyFloat_FromDouble(worst);
}

/* setpoint_check(values, limits, reference, max_step, cycles) -> (code, joint, worst): the
 * robot interface's setpoint plausibility (components/robot/interface.py,
 * RobotInterface._implausible_reference): code 1 if `values` is not 7 finite numbers,
 * 2 with the first joint beyond |limit|, else 0 with the joint of the largest step
 * ratio |v - r| / (max_step cycles) (of equal ratios the last; a NaN ratio never) */
static PyObject *py_setpoint_check(PyObject *self, PyObject *args)
{
    PyObject *vo, *lo, *ro, *so;
    long cycles;
    if (!PyArg_ParseTuple(args, "OOOOl", &vo, &lo, &ro, &so, &cycles))
        return NULL;
    double v[N], limit[N], r[N], step[N];
    int bad = numbers7(vo, v);
    if (bad < 0)
        return NULL;
    for (int i = 0; !bad && i < N; i++)
        bad = !isfinite(v[i]);
    if (bad)
        return Py_BuildValue("(iid)", 1, 0, -1.0);
    PyObject *rest[3] = {lo, ro, so};
    double *into[3] = {limit, r, step};
    for (int k = 0; k < 3; k++) {
        int wrong = numbers7(rest[k], into[k]);
        if (wrong < 0)
            return NULL;
        if (wrong) {
            PyErr_SetString(PyExc_ValueError, "setpoint_check: limits, reference and steps need 7 numbers");
            return NULL;
        }
    }
    for (int j = 0; j < N; j++)
        if (fabs(v[j]) > limit[j])
            return Py_BuildValue("(iid)", 2, j, -1.0);
    double worst = -1.0;
    int joint = 0;
    for (int k = 0; k < N; k++) {
        double ratio = fabs(v[k] - r[k]) / (step[k] * (double)cycles);
        if (ratio >= worst) {
            worst = ratio;
            joint = k;
        }
    }
    return Py_BuildValue("(iid)", 0, joint, worst);
}

/* -- FRI's socket: what arrived, read in one call ------------------------------------ */
#define FRI_BATCH 64 /* datagrams read per call at most: a flood is read over cycles */

/* one datagram (non-blocking): 1 and *item = (bytes, kernel arrival s, (host, port)), 0
 * when nothing waits, -1 on an error (set) */
static int fri_recv_one(int fd, PyObject **item)
{
    unsigned char buf[2048];
    char control[CMSG_SPACE(sizeof(struct timespec)) + 64];
    struct sockaddr_in from;
    struct iovec iov = {buf, sizeof buf};
    struct msghdr msg;
    memset(&msg, 0, sizeof msg);
    msg.msg_name = &from;
    msg.msg_namelen = sizeof from;
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    /* non-blocking: the interpreter lock is kept (giving it up and taking it back is a
     * chance for another thread to keep a real-time loop waiting) */
    ssize_t n = recvmsg(fd, &msg, MSG_DONTWAIT);
    if (n < 0) {
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return 0;
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    double stamp = -1.0;
    for (struct cmsghdr *c = CMSG_FIRSTHDR(&msg); c != NULL; c = CMSG_NXTHDR(&msg, c))
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_TIMESTAMPNS) {
            struct timespec ts;
            memcpy(&ts, CMSG_DATA(c), sizeof ts);
            stamp = (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
        }
    if (stamp < 0.0) { /* no kernel stamp (not asked for): now, as Python's time.time() */
        struct timespec now;
        clock_gettime(CLOCK_REALTIME, &now);
        stamp = (double)now.tv_sec + (double)now.tv_nsec * 1e-9;
    }
    char host[INET_ADDRSTRLEN] = "";
    if (from.sin_family == AF_INET)
        inet_ntop(AF_INET, &from.sin_addr, host, sizeof host);
    /* a datagram longer than the buffer is truncated, as Python's recvmsg(2048) has it */
    *item = Py_BuildValue("(y#d(si))", buf, (Py_ssize_t)(n > (ssize_t)sizeof buf ? (ssize_t)sizeof buf : n),
                          stamp, host, (int)ntohs(from.sin_port));
    return *item == NULL ? -1 : 1;
}

/* fri_receive(fd, timeout) -> [(datagram, arrival, (host, port)), ...]: every datagram
 * queued on the UDP socket `fd` (at most FRI_BATCH), oldest first, with the kernel's
 * arrival time (SO_TIMESTAMPNS, wall clock); if none is queued, it waits for one at most
 * `timeout` s (once) and reads what came. The FRI loops' read, without an exception per
 * empty queue. */
static PyObject *py_fri_receive(PyObject *self, PyObject *args)
{
    int fd;
    double timeout;
    if (!PyArg_ParseTuple(args, "id", &fd, &timeout))
        return NULL;
    PyObject *out = PyList_New(0);
    if (out == NULL)
        return NULL;
    for (int waited = 0;;) {
        PyObject *item = NULL;
        int got = fri_recv_one(fd, &item);
        if (got < 0)
            goto fail;
        if (got) {
            int appended = PyList_Append(out, item);
            Py_DECREF(item);
            if (appended < 0)
                goto fail;
            if (PyList_GET_SIZE(out) >= FRI_BATCH)
                break;
            continue;
        }
        if (PyList_GET_SIZE(out) > 0 || waited || timeout <= 0.0)
            break;
        struct pollfd pfd = {fd, POLLIN, 0};
        struct timespec wait;
        wait.tv_sec = (time_t)timeout;
        wait.tv_nsec = (long)((timeout - (double)wait.tv_sec) * 1e9);
        int ready;
        Py_BEGIN_ALLOW_THREADS ready = ppoll(&pfd, 1, &wait, NULL);
        Py_END_ALLOW_THREADS if (ready < 0 && errno != EINTR)
        {
            PyErr_SetFromErrno(PyExc_OSError);
            goto fail;
        }
        if (ready <= 0)
            break;
        waited = 1;
    }
    return out;
fail:
    Py_DECREF(out);
    return NULL;
}

static PyObject *tuple7(const double *v)
{
    PyObject *t = PyTuple_New(N);
    if (t == NULL)
        return NULL;
    for (int i = 0; i < N; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (f == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, i, f);
    }
    return t;
}

/* arm_sense(qpos[7], force[7], gravcomp[7], compliance[7], offset[7]) -> (q, aim, torque):
 * the simulated arm's encoders q = qpos + twist - offset and servo aim = offset - twist,
 * twist = (force + gravcomp) compliance, and its torques (components/sim/arm.py,
 * SimulatedArm._sense_reference: the same operations in the same order), as tuples */
static PyObject *py_arm_sense(PyObject *self, PyObject *args)
{
    PyObject *obj[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &obj[0], &obj[1], &obj[2], &obj[3], &obj[4]))
        return NULL;
    static const char *names[5] = {"qpos", "force", "gravcomp", "compliance", "offset"};
    Py_buffer b[5];
    int got = 0;
    for (; got < 5; got++)
        if (get_buffer(obj[got], &b[got], N, 0, names[got]) < 0)
            break;
    if (got < 5) {
        for (int i = 0; i < got; i++)
            PyBuffer_Release(&b[i]);
        return NULL;
    }
    const double *qpos = b[0].buf, *force = b[1].buf, *grav = b[2].buf, *comp = b[3].buf,
                 *off = b[4].buf;
    double q[N], aim[N], torque[N];
    for (int i = 0; i < N; i++) {
        double twist = (force[i] + grav[i]) * comp[i];
        q[i] = qpos[i] + twist - off[i];
        aim[i] = off[i] - twist;
        torque[i] = force[i];
    }
    for (int i = 0; i < 5; i++)
        PyBuffer_Release(&b[i]);
    return Py_BuildValue("(NNN)", tuple7(q), tuple7(aim), tuple7(torque));
}

static PyMethodDef methods[] = {
    {"arm_sense", py_arm_sense, METH_VARARGS,
     "arm_sense(qpos, force, gravcomp, compliance, offset) -> (q, aim, torque): the simulated "
     "arm's encoders, servo aim and torques."},
    {"fri_receive", py_fri_receive, METH_VARARGS,
     "fri_receive(fd, timeout) -> [(datagram, arrival, (host, port))]: what waits on the "
     "socket, or what comes within timeout if nothing does."},
    {"max_abs_diff", py_max_abs_diff, METH_VARARGS,
     "max_abs_diff(a, b) -> the largest |a_i - b_i| of 7, as Python's max() takes it."},
    {"setpoint_check", py_setpoint_check, METH_VARARGS,
     "setpoint_check(values, limits, reference, max_step, cycles) -> (code, joint, worst): "
     "1 not 7 finite, 2 a joint beyond its limit, 0 and the largest step ratio."},
    {"fri_encode_measurement", py_fri_encode_measurement, METH_VARARGS,
     "fri_encode_measurement(send_seq, refl_seq, timestamp, state, quality, stats, control, "
     "msr_jnt_pos, cmd_jnt_pos, cmd_jnt_pos_fri_offset, msr_jnt_trq, served, reason, cycle, "
     "braked, latched, sample_time) -> bytes."},
    {"fri_measurement", py_fri_measurement, METH_O,
     "fri_measurement(datagram) -> fri.Measurement's fields, or None for no measurement."},
    {"fri_command", py_fri_command, METH_O,
     "fri_command(datagram) -> fri.Command's fields, or None for no command."},
    {"fri_encode_command", py_fri_encode_command, METH_VARARGS,
     "fri_encode_command(send_seq, refl_seq, jnt_pos, request_number, request, flags) -> bytes."},
    {"steer_step", py_steer_step, METH_VARARGS,
     "steer_step(wanted, offset, budget, radius) -> size: the steering correction's step, "
     "offset moved in place."},
    {"servo_aim", py_servo_aim, METH_VARARGS,
     "servo_aim(values, reference, limit, aim, bound, reach, feed_forward, ctrl) -> joint: "
     "the simulated arm's setpoint guard and servo targets (-2: not 7 finite numbers; "
     "-1: ctrl written; else the joint of the step no arm can follow)."},
    {"path_pose", py_path_pose, METH_VARARGS,
     "path_pose(start, delta_p, delta_r, u, offset, out): the pose u of the way along the "
     "straight path, steering offset added."},
    {"jacobian", py_jacobian, METH_VARARGS,
     "jacobian(placements, tool, q, pose, jac): the TCP pose and its base-aligned 6x7 Jacobian."},
    {"joint_points", py_joint_points, METH_VARARGS,
     "joint_points(placements, tool, flange, q, out): base, joint origins, flange and TCP "
     "(10 x 3) into out."},
    {"ik_step", py_ik_step, METH_VARARGS,
     "ik_step(placements, tool, q, target, rest, lower, upper, max_step, out, damping2, "
     "rest_gain_dt) -> bool: one damped least-squares step into out."},
    {"capsule_min", py_capsule_min, METH_VARARGS,
     "capsule_min(a1, b1, r1, a2, b2, r2) -> (distance, i, j): the closest pair of capsules."},
    {"envelopes_decode", py_envelopes_decode, METH_VARARGS,
     "envelopes_decode(sample, prefix) -> (publisher, seq, stamp, values, na, nb, nr, finite, "
     "radii_ok), or None for what is not a whole Envelopes sample."},
    {"ssm_speed", py_ssm_speed, METH_VARARGS,
     "ssm_speed(a, b, rows, meta, now, window) -> (speed, tcp_speed): the fastest link capsule "
     "end over the window, the ends of now kept in the ring (rows, meta)."},
    {"ssm_check", py_ssm_check, METH_VARARGS,
     "ssm_check(ra, rb, rr, pa, pb, pr, rows, meta, terms, age, now, cap_age, dt) -> "
     "(separation, robot_speed, protective, cap, stop, tcp_speed, quiet): one cycle's speed and "
     "separation verdict, and the cycles of dt it holds for."},
    {"capsule_points", py_capsule_points, METH_VARARGS,
     "capsule_points(placements, tool, flange, q, pairs, a_out, b_out): the arm's link capsules' "
     "ends for joints q."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_fwkernel",
    "fw's compiled kernel: the numerics of the robot's 1 kHz cycle (see the C source).", -1,
    methods};

PyMODINIT_FUNC PyInit__fwkernel(void) { return PyModule_Create(&module); }
