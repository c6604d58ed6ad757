/* fieldbus_codec: the per-node and per-frame work of the POWERLINK nodes in C.
 *
 * A CPython extension module built on first use by fieldbus/codec.py. Each function
 * does exactly what a loop of fieldbus/nodes.py does, on the same Python objects
 * (python-can messages, the nodes' lists, numpy arrays through the buffer protocol),
 * with the same floating-point operations (compiled with -ffp-contract=off), so the
 * results are bit-identical. A function that meets anything unusual - a non-finite or
 * out-of-range value, an unexpected type or size - changes nothing and returns a
 * nonzero status; the caller then runs the Python code, which handles (saturates,
 * counts, reports) it.
 *
 *   pack_preq      quantise the set-points, pack the RPDO1 payloads (20 bytes), stamp the PReqs
 *   latch_pres     quantise the actual values, pack the TPDO1/TPDO2 payloads
 *   apply_due      apply the set-points due at the SoC (no comm fault latched)
 *   scale_into     telegram integers (list) times scale factors -> float64 array
 *   pres_frames    stamp and list the PRes frames of the nodes that answer
 *   receive_pres   digest TPDO1/TPDO2 frames at the MN, up to the first other frame
 *   receive_preq   digest RPDO1 frames (20 or classic 8 bytes) at the CNs, up to the first other frame
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <math.h>
#include <string.h>

#define MAX_NODES 127
#define RPDO1_BASE 0x200
#define TPDO1_BASE 0x180
#define TPDO2_BASE 0x280
#define SYNC_ID 0x080
#define RPDO1_LEN 20         /* controlword, target position, torque offset, mode, reserved, target torque,
                                target velocity, velocity offset */
#define RPDO1_CLASSIC_LEN 8  /* controlword, target position, torque offset (mode 8, the rest 0) */
#define TPDO2_LEN 7          /* velocity actual, error code, modes of operation display */
#define RECORD_SIZE 32       /* recorder record: timestamp, id, is_error_frame, dlc, 20 data bytes */
#define RECORD_DATA 20

enum { OK = 0, OUT_OF_RANGE = 1, UNSUPPORTED = 2, NOT_FINITE = -1, ERROR_CODE_CHANGED = 4 };

static PyObject *s_timestamp, *s_data, *s_arbitration_id, *s_is_error_frame, *s_is_remote_frame,
    *s_is_extended_id, *s_sync_seen, *s_sync_ts;

/* ------------------------------------------------------------------ buffers */

/* Numeric arrays are read through the buffer protocol. Acquiring a numpy buffer costs
 * several hundred instructions, so the views of the last CACHE_SIZE arrays are kept
 * (holding the export, which also keeps the object alive and its memory in place:
 * numpy refuses to resize an exported array). */
#define CACHE_SIZE 24

typedef struct {
    PyObject *obj;
    Py_buffer view;
    int itemsize;
    int is_float; /* float64 */
    int is_int;   /* int32 or int64 */
} Array;

static Array cache[CACHE_SIZE];
static int cache_next;

static Array *array_of(PyObject *obj)
{
    for (int i = 0; i < CACHE_SIZE; ++i)
        if (cache[i].obj == obj) return &cache[i];
    Array *a = &cache[cache_next];
    cache_next = (cache_next + 1) % CACHE_SIZE;
    if (a->obj != NULL) {
        PyBuffer_Release(&a->view);
        a->obj = NULL;
    }
    if (PyObject_GetBuffer(obj, &a->view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) {
        PyErr_Clear();
        return NULL;
    }
    a->obj = obj;
    const char *f = a->view.format ? a->view.format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    a->itemsize = (int)a->view.itemsize;
    a->is_float = (f[0] == 'd' && f[1] == 0 && a->itemsize == 8);
    a->is_int = ((f[0] == 'i' || f[0] == 'l' || f[0] == 'q') && f[1] == 0 && (a->itemsize == 4 || a->itemsize == 8));
    return a;
}

/* A C-contiguous 1-D array of n float64 (want_float) or int32/int64 items, or NULL. */
static const Array *array_get(PyObject *obj, Py_ssize_t n, int want_float)
{
    const Array *a = array_of(obj);
    if (a == NULL || a->view.len != n * a->view.itemsize || !(want_float ? a->is_float : a->is_int)) return NULL;
    return a;
}

static inline double array_double(const Array *a, Py_ssize_t i) { return ((const double *)a->view.buf)[i]; }

static inline long long array_int(const Array *a, Py_ssize_t i)
{
    return a->itemsize == 8 ? ((const long long *)a->view.buf)[i] : (long long)((const int *)a->view.buf)[i];
}

/* ------------------------------------------------------------------ message slots
 * python-can's Message keeps its attributes in __slots__; for the registered message
 * types (exact types whose attributes are those plain member slots, checked at
 * registration) they are read and written at their offsets, as the generic attribute
 * access does, without the lookup. Other objects go through PyObject_GetAttr/SetAttr. */
#define MAX_TYPES 8
static PyTypeObject *fast_types[MAX_TYPES];
static int n_fast_types;
static Py_ssize_t off_timestamp = -1, off_data, off_arbitration_id, off_is_error_frame, off_is_remote_frame,
                  off_is_extended_id;

#define SLOT(o, off) (*(PyObject **)((char *)(o) + (off)))

static inline int fast_message(PyObject *o)
{
    PyTypeObject *t = Py_TYPE(o);
    for (int i = 0; i < n_fast_types; ++i)
        if (t == fast_types[i]) return 1;
    return 0;
}

/* borrowed attribute value, or NULL (unset, or not a registered type: use get_attr) */
static inline PyObject *slot_get(PyObject *o, Py_ssize_t off) { return fast_message(o) ? SLOT(o, off) : NULL; }

/* new reference to msg.<name> (fast slot or generic), NULL with the error cleared */
static PyObject *get_attr(PyObject *msg, PyObject *name, Py_ssize_t off)
{
    PyObject *v = slot_get(msg, off);
    if (v != NULL) {
        Py_INCREF(v);
        return v;
    }
    v = PyObject_GetAttr(msg, name);
    if (v == NULL) PyErr_Clear();
    return v;
}

/* msg.<name> = value; -1 with an exception set on failure */
static int set_attr(PyObject *msg, PyObject *name, Py_ssize_t off, PyObject *value)
{
    if (fast_message(msg)) {
        PyObject *old = SLOT(msg, off);
        Py_INCREF(value);
        SLOT(msg, off) = value;
        Py_XDECREF(old);
        return 0;
    }
    return PyObject_SetAttr(msg, name, value);
}

static Py_ssize_t member_offset(PyTypeObject *type, PyObject *name)
{
    PyObject *descr = PyObject_GetAttr((PyObject *)type, name);
    Py_ssize_t off = -1;
    if (descr == NULL) {
        PyErr_Clear();
        return -1;
    }
    if (Py_IS_TYPE(descr, &PyMemberDescr_Type)) {
        PyMemberDef *m = ((PyMemberDescrObject *)descr)->d_member;
        if (m->type == T_OBJECT_EX && !(m->flags & READONLY)) off = m->offset;
    }
    Py_DECREF(descr);
    return off;
}

/* register_message_types(*types) -> int: how many of the types take the slot path */
static PyObject *register_message_types(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    for (Py_ssize_t k = 0; k < nargs; ++k) {
        if (!PyType_Check(args[k]) || n_fast_types == MAX_TYPES) continue;
        PyTypeObject *t = (PyTypeObject *)args[k];
        if (t->tp_getattro != PyObject_GenericGetAttr || t->tp_setattro != PyObject_GenericSetAttr ||
            t->tp_dictoffset != 0)
            continue;
        Py_ssize_t o[6] = {member_offset(t, s_timestamp), member_offset(t, s_data),
                           member_offset(t, s_arbitration_id), member_offset(t, s_is_error_frame),
                           member_offset(t, s_is_remote_frame), member_offset(t, s_is_extended_id)};
        int ok = 1;
        for (int i = 0; i < 6; ++i) ok &= (o[i] > 0);
        if (!ok) continue;
        if (off_timestamp < 0) {
            off_timestamp = o[0]; off_data = o[1]; off_arbitration_id = o[2];
            off_is_error_frame = o[3]; off_is_remote_frame = o[4]; off_is_extended_id = o[5];
        } else if (o[0] != off_timestamp || o[1] != off_data || o[2] != off_arbitration_id ||
                   o[3] != off_is_error_frame || o[4] != off_is_remote_frame || o[5] != off_is_extended_id) {
            continue;
        }
        int known = 0;
        for (int i = 0; i < n_fast_types; ++i) known |= (fast_types[i] == t);
        if (!known) {
            Py_INCREF(t);
            fast_types[n_fast_types++] = t;
        }
    }
    return PyLong_FromLong(n_fast_types);
}

/* n packed float64 constants held in a bytes object */
static const double *doubles_of(PyObject *obj, Py_ssize_t n)
{
    if (!PyBytes_Check(obj) || PyBytes_GET_SIZE(obj) != n * (Py_ssize_t)sizeof(double)) return NULL;
    return (const double *)PyBytes_AS_STRING(obj);
}

/* the bytearray payload of a message, exactly `size` bytes, or NULL (error cleared) */
static unsigned char *payload_of(PyObject *msg, Py_ssize_t size)
{
    PyObject *data = get_attr(msg, s_data, off_data);
    if (data == NULL) return NULL;
    unsigned char *out = NULL;
    if (PyByteArray_CheckExact(data) && PyByteArray_GET_SIZE(data) == size)
        out = (unsigned char *)PyByteArray_AS_STRING(data);
    Py_DECREF(data); /* the message keeps the bytearray alive */
    return out;
}

static inline void put_u16(unsigned char *p, long long v) { p[0] = (unsigned char)(v & 0xFF); p[1] = (unsigned char)((v >> 8) & 0xFF); }
static inline void put_i32(unsigned char *p, long long v)
{
    unsigned long u = (unsigned long)(v & 0xFFFFFFFFLL);
    p[0] = (unsigned char)(u & 0xFF); p[1] = (unsigned char)((u >> 8) & 0xFF);
    p[2] = (unsigned char)((u >> 16) & 0xFF); p[3] = (unsigned char)((u >> 24) & 0xFF);
}
static inline long get_u16(const unsigned char *p) { return (long)p[0] | ((long)p[1] << 8); }
static inline long get_i8(const unsigned char *p) { return (long)(signed char)p[0]; }
static inline long get_i16(const unsigned char *p) { return (long)(short)(unsigned short)((unsigned)p[0] | ((unsigned)p[1] << 8)); }
static inline long get_i32(const unsigned char *p)
{
    unsigned int u = (unsigned)p[0] | ((unsigned)p[1] << 8) | ((unsigned)p[2] << 16) | ((unsigned)p[3] << 24);
    return (long)(int)u;
}

/* list[i] = new object (reference stolen), dropping the old item */
static void list_replace(PyObject *list, Py_ssize_t i, PyObject *o)
{
    PyObject *old = PyList_GET_ITEM(list, i);
    PyList_SET_ITEM(list, i, o);
    Py_XDECREF(old);
}

static int list_replace_long(PyObject *list, Py_ssize_t i, long long v)
{
    PyObject *o = PyLong_FromLongLong(v);
    if (o == NULL) return -1;
    list_replace(list, i, o);
    return 0;
}

static int list_replace_double(PyObject *list, Py_ssize_t i, double v)
{
    PyObject *o = PyFloat_FromDouble(v);
    if (o == NULL) return -1;
    list_replace(list, i, o);
    return 0;
}

static int list_replace_bool(PyObject *list, Py_ssize_t i, int v)
{
    PyObject *o = v ? Py_True : Py_False;
    Py_INCREF(o);
    list_replace(list, i, o);
    return 0;
}

#define CHECK_ARGS(count)                                                               \
    if (nargs != (count)) {                                                             \
        PyErr_Format(PyExc_TypeError, "expected %d arguments, got %zd", (count), nargs); \
        return NULL;                                                                    \
    }

/* ------------------------------------------------------------------ pack_preq
 * pack_preq(msgs, times, controlword, position, torque, mode, target_torque, target_velocity,
 *           velocity_offset, cpr, upn, wait, latest, last_cw) -> int
 * ManagingNode.frames for the PReqs: msgs[i] (RPDO1 of node i+1) gets timestamp times[i+1]
 * and the payload (controlword, floor(position*cpr+0.5), floor(torque*upn+0.5), mode, 0,
 * floor(target_torque*upn+0.5), floor(target_velocity*cpr+0.5), floor(velocity_offset*cpr+0.5));
 * latest[i] = times[i+1] + wait[i]; last_cw[i] = controlword[i]. A mode other than 8, 9,
 * 10 is OUT_OF_RANGE (the Python code raises the error naming it). */
static PyObject *pack_preq(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(14);
    PyObject *msgs = args[0], *times = args[1], *latest = args[12], *last_cw = args[13];
    if (!PyList_CheckExact(msgs) || !PyList_CheckExact(times) || !PyList_CheckExact(latest) ||
        !PyList_CheckExact(last_cw))
        return PyLong_FromLong(UNSUPPORTED);
    Py_ssize_t n = PyList_GET_SIZE(msgs);
    if (n < 1 || n > MAX_NODES || PyList_GET_SIZE(times) < n + 1 || PyList_GET_SIZE(latest) != n ||
        PyList_GET_SIZE(last_cw) != n)
        return PyLong_FromLong(UNSUPPORTED);
    const double *cpr = doubles_of(args[9], n), *upn = doubles_of(args[10], n), *wait = doubles_of(args[11], n);
    if (!cpr || !upn || !wait) return PyLong_FromLong(UNSUPPORTED);
    int status = OK;
    const Array *cwa = array_get(args[2], n, 0), *posa = array_get(args[3], n, 1), *tqa = array_get(args[4], n, 1);
    if (cwa == NULL || posa == NULL || tqa == NULL) return PyLong_FromLong(UNSUPPORTED);
    const Array cw = *cwa, pos = *posa, tq = *tqa;
    const Array *modea = array_get(args[5], n, 0), *tta = array_get(args[6], n, 1), *tva = array_get(args[7], n, 1),
                *voa = array_get(args[8], n, 1);
    if (modea == NULL || tta == NULL || tva == NULL || voa == NULL) return PyLong_FromLong(UNSUPPORTED);
    const Array mode = *modea, tt = *tta, tv = *tva, vo = *voa;
    long long cwv[MAX_NODES], counts[MAX_NODES], units[MAX_NODES], modev[MAX_NODES], ttu[MAX_NODES],
        tvc[MAX_NODES], voc[MAX_NODES];
    unsigned char *payload[MAX_NODES];
    for (Py_ssize_t i = 0; i < n; ++i) {
        double x = array_double(&pos, i) * cpr[i] + 0.5;
        double y = array_double(&tq, i) * upn[i] + 0.5;
        double a = array_double(&tt, i) * upn[i] + 0.5;
        double b = array_double(&tv, i) * cpr[i] + 0.5;
        double c = array_double(&vo, i) * cpr[i] + 0.5;
        if (!isfinite(x) || !isfinite(y) || !isfinite(a) || !isfinite(b) || !isfinite(c)) {
            status = NOT_FINITE;
            goto done;
        }
        double fx = floor(x), fy = floor(y), fa = floor(a), fb = floor(b), fc = floor(c);
        cwv[i] = array_int(&cw, i);
        modev[i] = array_int(&mode, i);
        if (cwv[i] < 0 || cwv[i] > 0xFFFF || fx < -2147483648.0 || fx > 2147483647.0 || fy < -32768.0 ||
            fy > 32767.0 || fa < -32768.0 || fa > 32767.0 || fb < -2147483648.0 || fb > 2147483647.0 ||
            fc < -2147483648.0 || fc > 2147483647.0 || modev[i] < 8 || modev[i] > 10) {
            status = OUT_OF_RANGE;
            goto done;
        }
        counts[i] = (long long)fx;
        units[i] = (long long)fy;
        ttu[i] = (long long)fa;
        tvc[i] = (long long)fb;
        voc[i] = (long long)fc;
        if (!PyFloat_CheckExact(PyList_GET_ITEM(times, i + 1))) { status = UNSUPPORTED; goto done; }
        payload[i] = payload_of(PyList_GET_ITEM(msgs, i), RPDO1_LEN);
        if (payload[i] == NULL) { status = UNSUPPORTED; goto done; }
    }
    for (Py_ssize_t i = 0; i < n; ++i) {
        PyObject *ts = PyList_GET_ITEM(times, i + 1);
        if (set_attr(PyList_GET_ITEM(msgs, i), s_timestamp, off_timestamp, ts) != 0) { status = -3; goto done; }
        unsigned char *p = payload[i];
        put_u16(p, cwv[i]);
        put_i32(p + 2, counts[i]);
        put_u16(p + 6, units[i]);
        p[8] = (unsigned char)modev[i];
        p[9] = 0;
        put_u16(p + 10, ttu[i]);
        put_i32(p + 12, tvc[i]);
        put_i32(p + 16, voc[i]);
        if (list_replace_double(latest, i, PyFloat_AS_DOUBLE(ts) + wait[i]) || list_replace_long(last_cw, i, cwv[i])) {
            status = -3;
            goto done;
        }
    }
done:
    if (status == -3) return NULL;
    return PyLong_FromLong(status);
}

/* ------------------------------------------------------------------ latch_pres
 * latch_pres(statusword, position, velocity, torque, error_code, mode_display, cpr, upn, msgs1, msgs2,
 *            a_pos) -> int
 * ControlledNodes.start_cycle's quantisation and ControlledNodes.responses' packing:
 * msgs1[i] (TPDO1) <- (statusword, floor(position*cpr+0.5), floor(torque*upn+0.5)),
 * msgs2[i] (TPDO2) <- (floor(velocity*cpr+0.5), error_code, mode_display); a_pos[i] = the position count.
 * Returns ERROR_CODE_CHANGED (4) instead of OK when a drive's error code (0x603F) differs from the
 * one its TPDO2 payload held (the last cycle's), so that the node can send its EMCY. */
static PyObject *latch_pres(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(11);
    PyObject *msgs1 = args[8], *msgs2 = args[9], *a_pos = args[10];
    if (!PyList_CheckExact(msgs1) || !PyList_CheckExact(msgs2) || !PyList_CheckExact(a_pos))
        return PyLong_FromLong(UNSUPPORTED);
    Py_ssize_t n = PyList_GET_SIZE(msgs1);
    if (n < 1 || n > MAX_NODES || PyList_GET_SIZE(msgs2) != n || PyList_GET_SIZE(a_pos) != n)
        return PyLong_FromLong(UNSUPPORTED);
    const double *cpr = doubles_of(args[6], n), *upn = doubles_of(args[7], n);
    if (!cpr || !upn) return PyLong_FromLong(UNSUPPORTED);
    int status = OK;
    const Array *swa = array_get(args[0], n, 0), *posa = array_get(args[1], n, 1), *vela = array_get(args[2], n, 1),
                *tqa = array_get(args[3], n, 1), *erra = array_get(args[4], n, 0), *modea = array_get(args[5], n, 0);
    if (swa == NULL || posa == NULL || vela == NULL || tqa == NULL || erra == NULL || modea == NULL)
        return PyLong_FromLong(UNSUPPORTED);
    const Array sw = *swa, pos = *posa, vel = *vela, tq = *tqa, err = *erra, mode = *modea;
    long long swv[MAX_NODES], errv[MAX_NODES], pc[MAX_NODES], vc[MAX_NODES], tc[MAX_NODES], mv[MAX_NODES];
    unsigned char *p1[MAX_NODES], *p2[MAX_NODES];
    for (Py_ssize_t i = 0; i < n; ++i) {
        double x = array_double(&pos, i) * cpr[i] + 0.5;
        double v = array_double(&vel, i) * cpr[i] + 0.5;
        double t = array_double(&tq, i) * upn[i] + 0.5;
        if (!isfinite(x) || !isfinite(v) || !isfinite(t)) { status = NOT_FINITE; goto done; }
        double fx = floor(x), fv = floor(v), ft = floor(t);
        swv[i] = array_int(&sw, i);
        errv[i] = array_int(&err, i);
        mv[i] = array_int(&mode, i);
        if (swv[i] < 0 || swv[i] > 0xFFFF || errv[i] < 0 || errv[i] > 0xFFFF || mv[i] < -128 || mv[i] > 127 ||
            fx < -2147483648.0 ||
            fx > 2147483647.0 || fv < -2147483648.0 || fv > 2147483647.0 || ft < -32768.0 || ft > 32767.0) {
            status = OUT_OF_RANGE;
            goto done;
        }
        pc[i] = (long long)fx;
        vc[i] = (long long)fv;
        tc[i] = (long long)ft;
        p1[i] = payload_of(PyList_GET_ITEM(msgs1, i), 8);
        p2[i] = payload_of(PyList_GET_ITEM(msgs2, i), TPDO2_LEN);
        if (p1[i] == NULL || p2[i] == NULL) { status = UNSUPPORTED; goto done; }
    }
    for (Py_ssize_t i = 0; i < n; ++i) {
        if (get_u16(p2[i] + 4) != errv[i]) status = ERROR_CODE_CHANGED;
        put_u16(p1[i], swv[i]);
        put_i32(p1[i] + 2, pc[i]);
        put_u16(p1[i] + 6, tc[i]);
        put_i32(p2[i], vc[i]);
        put_u16(p2[i] + 4, errv[i]);
        p2[i][6] = (unsigned char)(mv[i] & 0xFF);
        if (list_replace_long(a_pos, i, pc[i])) { status = -3; goto done; }
    }
done:
    if (status == -3) return NULL;
    return PyLong_FromLong(status);
}

/* ------------------------------------------------------------------ apply_due
 * apply_due(pipe, slot, cws, poss, prev, tqs, modes, tts, tvs, vos, fresh, a_pos, hold) -> int (1: all fresh)
 * ControlledNodes.start_cycle's application of the set-points due at this SoC when no
 * comm fault is latched: pipe[i][slot] = (cw, pos, tq, mode, reserved, tt, tv, vo) or None. */
static PyObject *apply_due(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(13);
    PyObject *pipe = args[0], *cws = args[2], *poss = args[3], *prev = args[4], *tqs = args[5], *fresh = args[10],
             *a_pos = args[11];
    PyObject *extra[4] = {args[6], args[7], args[8], args[9]}; /* modes, tts, tvs, vos */
    static const int extra_item[4] = {3, 5, 6, 7};
    Py_ssize_t slot = PyLong_AsSsize_t(args[1]);
    int hold = PyObject_IsTrue(args[12]);
    if ((slot == -1 && PyErr_Occurred()) || hold < 0) return NULL;
    Py_ssize_t n = PyList_Check(pipe) ? PyList_GET_SIZE(pipe) : -1;
    if (n < 1 || !PyList_CheckExact(cws) || !PyList_CheckExact(poss) || !PyList_CheckExact(prev) ||
        !PyList_CheckExact(tqs) || !PyList_CheckExact(fresh) || !PyList_CheckExact(a_pos) ||
        PyList_GET_SIZE(cws) != n || PyList_GET_SIZE(poss) != n || PyList_GET_SIZE(prev) != n ||
        PyList_GET_SIZE(tqs) != n || PyList_GET_SIZE(fresh) != n || PyList_GET_SIZE(a_pos) != n)
        return PyLong_FromLong(-UNSUPPORTED);
    for (int e = 0; e < 4; ++e)
        if (!PyList_CheckExact(extra[e]) || PyList_GET_SIZE(extra[e]) != n) return PyLong_FromLong(-UNSUPPORTED);
    for (Py_ssize_t i = 0; i < n; ++i) {
        PyObject *slots = PyList_GET_ITEM(pipe, i);
        if (!PyList_CheckExact(slots) || slot < 0 || slot >= PyList_GET_SIZE(slots)) return PyLong_FromLong(-UNSUPPORTED);
        PyObject *due = PyList_GET_ITEM(slots, slot);
        if (due != Py_None && !(PyTuple_CheckExact(due) && PyTuple_GET_SIZE(due) == 8)) return PyLong_FromLong(-UNSUPPORTED);
    }
    int all_fresh = 1;
    for (Py_ssize_t i = 0; i < n; ++i) {
        PyObject *slots = PyList_GET_ITEM(pipe, i);
        PyObject *due = PyList_GET_ITEM(slots, slot);
        if (due != Py_None) {
            Py_INCREF(due);
            Py_INCREF(Py_None);
            list_replace(slots, slot, Py_None);
            PyObject *cw = PyTuple_GET_ITEM(due, 0), *p = PyTuple_GET_ITEM(due, 1), *t = PyTuple_GET_ITEM(due, 2);
            Py_INCREF(cw);
            list_replace(cws, i, cw);
            PyObject *old = PyList_GET_ITEM(poss, i);
            Py_INCREF(old);
            list_replace(prev, i, old);
            Py_INCREF(p);
            list_replace(poss, i, p);
            Py_INCREF(t);
            list_replace(tqs, i, t);
            for (int e = 0; e < 4; ++e) {
                PyObject *v = PyTuple_GET_ITEM(due, extra_item[e]);
                Py_INCREF(v);
                list_replace(extra[e], i, v);
            }
            list_replace_bool(fresh, i, 1);
            Py_DECREF(due);
        } else {
            all_fresh = 0;
            list_replace_bool(fresh, i, 0);
            PyObject *last = PyList_GET_ITEM(poss, i);
            if (last == Py_None) {
                PyObject *a = PyList_GET_ITEM(a_pos, i);
                Py_INCREF(a);
                list_replace(poss, i, a);
            } else if (!hold && PyList_GET_ITEM(prev, i) != Py_None) {
                PyObject *diff = PyNumber_Subtract(last, PyList_GET_ITEM(prev, i));
                if (diff == NULL) return NULL;
                PyObject *next = PyNumber_Add(last, diff);
                Py_DECREF(diff);
                if (next == NULL) return NULL;
                /* one cycle extrapolated, then held: prev = poss makes the next step zero */
                Py_INCREF(next);
                list_replace(prev, i, next);
                list_replace(poss, i, next);
            }
        }
    }
    return PyLong_FromLong(all_fresh);
}

/* ------------------------------------------------------------------ scale_into
 * scale_into(values, scale, out) -> int: out[i] = values[i] * scale[i] (Python's int * float:
 * the integer converted to the nearest double first). 0 done; nonzero: nothing written. */
static PyObject *scale_into(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(3);
    PyObject *values = args[0];
    if (!PyList_CheckExact(values)) return PyLong_FromLong(UNSUPPORTED);
    Py_ssize_t n = PyList_GET_SIZE(values);
    const double *scale = doubles_of(args[1], n);
    if (n < 1 || n > MAX_NODES || scale == NULL) return PyLong_FromLong(UNSUPPORTED);
    double tmp[MAX_NODES];
    for (Py_ssize_t i = 0; i < n; ++i) {
        PyObject *v = PyList_GET_ITEM(values, i);
        double d;
        if (PyLong_CheckExact(v)) {
            d = PyLong_AsDouble(v);
            if (d == -1.0 && PyErr_Occurred()) { PyErr_Clear(); return PyLong_FromLong(UNSUPPORTED); }
        } else if (PyFloat_CheckExact(v)) {
            d = PyFloat_AS_DOUBLE(v);
        } else {
            return PyLong_FromLong(UNSUPPORTED);
        }
        tmp[i] = d * scale[i];
    }
    const Array *out = array_get(args[2], n, 1);
    if (out == NULL || out->view.readonly) return PyLong_FromLong(UNSUPPORTED);
    memcpy(out->view.buf, tmp, (size_t)n * sizeof(double));
    return PyLong_FromLong(OK);
}

/* ------------------------------------------------------------------ pres_frames
 * pres_frames(msgs1, msgs2, times, ok, late) -> list: ControlledNodes.responses without
 * packing (done by latch_pres): for each node whose PReq arrived (ok or late) and whose
 * PRes time times[n+1+i] is not None, both messages stamped with it, in order. */
static PyObject *pres_frames(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(5);
    PyObject *msgs1 = args[0], *msgs2 = args[1], *times = args[2], *ok = args[3], *late = args[4];
    if (!PyList_CheckExact(msgs1) || !PyList_CheckExact(msgs2) || !PyList_CheckExact(times) ||
        !PyList_CheckExact(ok) || !PyList_CheckExact(late)) {
        PyErr_SetString(PyExc_TypeError, "pres_frames: expected lists");
        return NULL;
    }
    Py_ssize_t n = PyList_GET_SIZE(msgs1);
    if (PyList_GET_SIZE(msgs2) != n || PyList_GET_SIZE(ok) != n || PyList_GET_SIZE(late) != n ||
        PyList_GET_SIZE(times) < 2 * n + 1) {
        PyErr_SetString(PyExc_ValueError, "pres_frames: inconsistent lengths");
        return NULL;
    }
    PyObject *out = PyList_New(0);
    if (out == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; ++i) {
        PyObject *ts = PyList_GET_ITEM(times, n + 1 + i);
        int answered = PyObject_IsTrue(PyList_GET_ITEM(ok, i));
        if (answered < 0) goto fail;
        if (!answered) {
            answered = PyObject_IsTrue(PyList_GET_ITEM(late, i));
            if (answered < 0) goto fail;
        }
        if (!answered || ts == Py_None) continue;
        PyObject *m1 = PyList_GET_ITEM(msgs1, i), *m2 = PyList_GET_ITEM(msgs2, i);
        if (set_attr(m1, s_timestamp, off_timestamp, ts) || set_attr(m2, s_timestamp, off_timestamp, ts) ||
            PyList_Append(out, m1) || PyList_Append(out, m2))
            goto fail;
    }
    return out;
fail:
    Py_DECREF(out);
    return NULL;
}

/* ------------------------------------------------------------------ frame attributes */

typedef struct {
    long id;
    double timestamp;
    const unsigned char *data;
    Py_ssize_t size;
    int plain; /* not an error, remote or extended frame */
    PyObject *hold; /* a reference to the data object, keeping `data` alive while used */
} Frame;

static inline int truth(PyObject *o)
{
    if (o == Py_False) return 0;
    if (o == Py_True) return 1;
    return PyObject_IsTrue(o);
}

/* Reads what the nodes look at; 0 ok (the caller releases f->hold), 1 not readable this
 * way (the caller hands the frame to Python), -1 error. */
static int frame_read(PyObject *msg, Frame *f)
{
    f->hold = NULL;
    PyObject *e = get_attr(msg, s_is_error_frame, off_is_error_frame);
    PyObject *r = get_attr(msg, s_is_remote_frame, off_is_remote_frame);
    PyObject *x = get_attr(msg, s_is_extended_id, off_is_extended_id);
    PyObject *id = get_attr(msg, s_arbitration_id, off_arbitration_id);
    PyObject *ts = get_attr(msg, s_timestamp, off_timestamp);
    PyObject *d = get_attr(msg, s_data, off_data);
    int result = 1;
    if (e && r && x && id && ts && d) {
        /* `is_error_frame or is_remote_frame or is_extended_id`, evaluated in that order */
        int flag = truth(e);
        if (flag == 0) flag = truth(r);
        if (flag == 0) flag = truth(x);
        if (flag < 0) PyErr_Clear();
        f->plain = (flag == 0);
        if (f->plain && PyLong_CheckExact(id) && PyFloat_CheckExact(ts)) {
            f->id = PyLong_AsLong(id);
            f->timestamp = PyFloat_AS_DOUBLE(ts);
            if (f->id == -1 && PyErr_Occurred()) {
                PyErr_Clear();
            } else if (PyByteArray_CheckExact(d)) {
                f->data = (const unsigned char *)PyByteArray_AS_STRING(d);
                f->size = PyByteArray_GET_SIZE(d);
                result = 0;
            } else if (PyBytes_CheckExact(d)) {
                f->data = (const unsigned char *)PyBytes_AS_STRING(d);
                f->size = PyBytes_GET_SIZE(d);
                result = 0;
            }
        }
    }
    Py_XDECREF(e);
    Py_XDECREF(r);
    Py_XDECREF(x);
    Py_XDECREF(id);
    Py_XDECREF(ts);
    if (result == 0) {
        f->hold = d;
    } else {
        Py_XDECREF(d);
    }
    return result;
}

/* The receive loops' step: msgs[k] read by frame_read (1) while k < len(msgs); 0 ends the
 * loop at k (the end, or a frame the caller hands to Python). */
static inline int frame_at(PyObject *msgs, Py_ssize_t k, Frame *f)
{
    return k < PySequence_Fast_GET_SIZE(msgs) && frame_read(PySequence_Fast_GET_ITEM(msgs, k), f) == 0;
}

/* ------------------------------------------------------------------ receive_pres
 * receive_pres(msgs, start, latest, sw, pos, tq, vel, err, mode, got1, got2, late) -> int
 * ManagingNode.receive_all's loop from msgs[start] on, for the frames it decodes itself
 * (plain TPDO1 of 8 bytes / TPDO2 of 7 bytes of nodes 1..n); returns the index of the
 * first other frame (for ManagingNode._other_frame), or len(msgs). */
static PyObject *receive_pres(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(12);
    PyObject *msgs = args[0], *latest = args[2];
    PyObject *sw = args[3], *pos = args[4], *tq = args[5], *vel = args[6], *err = args[7], *mode = args[8],
             *got1 = args[9], *got2 = args[10], *late = args[11];
    Py_ssize_t start = PyLong_AsSsize_t(args[1]);
    if (start == -1 && PyErr_Occurred()) return NULL;
    if (!(PyList_CheckExact(msgs) || PyTuple_CheckExact(msgs)) || !PyList_CheckExact(latest)) {
        PyErr_SetString(PyExc_TypeError, "receive_pres: expected a list of messages and a list of times");
        return NULL;
    }
    Py_ssize_t n = PyList_GET_SIZE(latest);
    PyObject *lists[9] = {sw, pos, tq, vel, err, mode, got1, got2, late};
    for (int k = 0; k < 9; ++k)
        if (!PyList_CheckExact(lists[k]) || PyList_GET_SIZE(lists[k]) != n) {
            PyErr_SetString(PyExc_TypeError, "receive_pres: inconsistent node lists");
            return NULL;
        }
    Frame f;
    Py_ssize_t k;
    for (k = start; frame_at(msgs, k, &f); ++k) {
        long base = f.id & ~0x7FL, node = f.id & 0x7FL;
        int kind = 0;
        if (node >= 1 && node <= n && f.id <= 0x7FF) {
            if (base == TPDO1_BASE && f.size == 8) kind = 1;
            else if (base == TPDO2_BASE && f.size == TPDO2_LEN) kind = 2;
        }
        if (kind == 0) { Py_DECREF(f.hold); break; }
        Py_ssize_t i = node - 1;
        PyObject *lim = PyList_GET_ITEM(latest, i);
        double limit = PyFloat_Check(lim) ? PyFloat_AS_DOUBLE(lim) : PyFloat_AsDouble(lim);
        if (limit == -1.0 && PyErr_Occurred()) { Py_DECREF(f.hold); return NULL; }
        int failed = 0;
        if (f.timestamp > limit) {
            list_replace_bool(late, i, 1);
        } else if (kind == 1) {
            failed = list_replace_long(sw, i, get_u16(f.data)) || list_replace_long(pos, i, get_i32(f.data + 2)) ||
                     list_replace_long(tq, i, get_i16(f.data + 6));
            list_replace_bool(got1, i, 1);
        } else {
            failed = list_replace_long(vel, i, get_i32(f.data)) || list_replace_long(err, i, get_u16(f.data + 4)) ||
                     list_replace_long(mode, i, get_i8(f.data + 6));
            list_replace_bool(got2, i, 1);
        }
        Py_DECREF(f.hold);
        if (failed) return NULL;
    }
    return PyLong_FromSsize_t(k);
}

/* ------------------------------------------------------------------ receive_preq
 * receive_preq(msgs, start, pipe, slot, arrival, next_soc, ok, late, node, sync_counter) -> int
 * ControlledNodes.receive_all's loop from msgs[start] on for plain RPDO1 frames of 20
 * (or classic 8) bytes of nodes 1..n (late when timestamp + arrival[i] > next_soc, else
 * pipe[i][slot] = (controlword, target, torque, mode, reserved, target torque, target
 * velocity, velocity offset), a classic frame with (8, 0, 0, 0, 0) for the last five,
 * and ok[i]) and for a plain SYNC of at most one byte
 * carrying no counter or ``sync_counter`` (node._sync_seen = True, node._sync_ts = its
 * timestamp); returns the index of the first other frame (for
 * ControlledNodes._other_frame: a wrong counter, other traffic, bad frames) or len(msgs). */
static PyObject *receive_preq(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(10);
    PyObject *msgs = args[0], *pipe = args[2], *ok = args[6], *late = args[7], *node_obj = args[8];
    Py_ssize_t start = PyLong_AsSsize_t(args[1]);
    Py_ssize_t slot = PyLong_AsSsize_t(args[3]);
    double next_soc = PyFloat_AsDouble(args[5]);
    long sync_counter = PyLong_AsLong(args[9]);
    if (((start == -1 || slot == -1 || sync_counter == -1) && PyErr_Occurred()) ||
        (next_soc == -1.0 && PyErr_Occurred()))
        return NULL;
    if (!(PyList_CheckExact(msgs) || PyTuple_CheckExact(msgs)) || !PyList_CheckExact(pipe) ||
        !PyList_CheckExact(ok) || !PyList_CheckExact(late)) {
        PyErr_SetString(PyExc_TypeError, "receive_preq: expected lists");
        return NULL;
    }
    Py_ssize_t n = PyList_GET_SIZE(pipe);
    const double *arrival = doubles_of(args[4], n);
    if (arrival == NULL || PyList_GET_SIZE(ok) != n || PyList_GET_SIZE(late) != n) {
        PyErr_SetString(PyExc_TypeError, "receive_preq: inconsistent node lists");
        return NULL;
    }
    Frame f;
    Py_ssize_t k;
    for (k = start; frame_at(msgs, k, &f); ++k) {
        if (f.id == SYNC_ID && f.size <= 1) {
            if (f.size == 1 && (long)f.data[0] != sync_counter) { Py_DECREF(f.hold); break; }
            PyObject *ts = PyFloat_FromDouble(f.timestamp);
            Py_DECREF(f.hold);
            if (ts == NULL) return NULL;
            int failed = PyObject_SetAttr(node_obj, s_sync_seen, Py_True) || PyObject_SetAttr(node_obj, s_sync_ts, ts);
            Py_DECREF(ts);
            if (failed) return NULL;
            continue;
        }
        long node = f.id & 0x7FL;
        if (!((f.id & ~0x7FL) == RPDO1_BASE && node >= 1 && node <= n &&
              (f.size == RPDO1_LEN || f.size == RPDO1_CLASSIC_LEN))) {
            Py_DECREF(f.hold);
            break;
        }
        Py_ssize_t i = node - 1;
        PyObject *slots = PyList_GET_ITEM(pipe, i);
        if (!PyList_CheckExact(slots) || slot < 0 || slot >= PyList_GET_SIZE(slots)) {
            Py_DECREF(f.hold);
            PyErr_SetString(PyExc_TypeError, "receive_preq: bad pipe");
            return NULL;
        }
        if (f.timestamp + arrival[i] > next_soc) {
            list_replace_bool(late, i, 1);
        } else {
            PyObject *due = PyTuple_New(8);
            if (due == NULL) { Py_DECREF(f.hold); return NULL; }
            int fd = f.size == RPDO1_LEN;
            long v[8] = {get_u16(f.data), get_i32(f.data + 2), get_i16(f.data + 6), fd ? get_i8(f.data + 8) : 8,
                         fd ? (long)f.data[9] : 0, fd ? get_i16(f.data + 10) : 0, fd ? get_i32(f.data + 12) : 0,
                         fd ? get_i32(f.data + 16) : 0};
            for (int e = 0; e < 8; ++e) {
                PyObject *o = PyLong_FromLong(v[e]);
                if (o == NULL) { Py_DECREF(due); Py_DECREF(f.hold); return NULL; }
                PyTuple_SET_ITEM(due, e, o);
            }
            list_replace(slots, slot, due);
            list_replace_bool(ok, i, 1);
        }
        Py_DECREF(f.hold);
    }
    return PyLong_FromSsize_t(k);
}

/* ------------------------------------------------------------------ pack_records
 * pack_records(frames) -> bytes | None: the FrameRecorder's records of `frames`, as
 * b"".join(RECORD.pack(m.timestamp, m.arbitration_id, m.is_error_frame, len(m.data), m.data))
 * with RECORD = struct.Struct("<dHBB20s") would make them; None (the caller packs in Python,
 * which raises struct.error) when a value does not fit that layout. */
/* One record of `msg` at `p`; 0 (nothing written) when a value does not fit the layout. */
static int pack_record(PyObject *msg, unsigned char *p)
{
    if (fast_message(msg)) { /* the frames the nodes send: borrowed slots, exact types */
        PyObject *ts = SLOT(msg, off_timestamp), *id = SLOT(msg, off_arbitration_id);
        PyObject *err = SLOT(msg, off_is_error_frame), *data = SLOT(msg, off_data);
        if (ts && id && data && PyFloat_CheckExact(ts) && PyLong_CheckExact(id) && (err == Py_False || err == Py_True) &&
            PyByteArray_CheckExact(data)) {
            long idv = PyLong_AsLong(id);
            Py_ssize_t size = PyByteArray_GET_SIZE(data);
            if (idv >= 0 && idv <= 0xFFFF && size <= 0xFF) {
                double t = PyFloat_AS_DOUBLE(ts);
                memcpy(p, &t, 8);
                p[8] = (unsigned char)(idv & 0xFF);
                p[9] = (unsigned char)((idv >> 8) & 0xFF);
                p[10] = (unsigned char)(err == Py_True);
                p[11] = (unsigned char)size;
                memset(p + 12, 0, RECORD_DATA);
                memcpy(p + 12, PyByteArray_AS_STRING(data), (size_t)(size < RECORD_DATA ? size : RECORD_DATA));
                return 1;
            }
            if (idv == -1) PyErr_Clear(); /* overflow: the general path below declines it too */
        }
    }
    PyObject *ts = get_attr(msg, s_timestamp, off_timestamp);
    PyObject *id = get_attr(msg, s_arbitration_id, off_arbitration_id);
    PyObject *err = get_attr(msg, s_is_error_frame, off_is_error_frame);
    PyObject *data = get_attr(msg, s_data, off_data);
    int ok = ts && id && err && data && (PyFloat_CheckExact(ts) || PyLong_CheckExact(ts)) && PyLong_Check(id) &&
             PyLong_Check(err) && (PyByteArray_CheckExact(data) || PyBytes_CheckExact(data));
    double t = 0.0;
    long idv = -1, errv = -1;
    Py_ssize_t size = 0;
    const char *bytes = NULL;
    if (ok) {
        t = PyFloat_CheckExact(ts) ? PyFloat_AS_DOUBLE(ts) : PyLong_AsDouble(ts);
        idv = PyLong_AsLong(id);
        errv = PyLong_AsLong(err);
        if (PyErr_Occurred()) PyErr_Clear();
        size = PyByteArray_CheckExact(data) ? PyByteArray_GET_SIZE(data) : PyBytes_GET_SIZE(data);
        bytes = PyByteArray_CheckExact(data) ? PyByteArray_AS_STRING(data) : PyBytes_AS_STRING(data);
        ok = (idv >= 0 && idv <= 0xFFFF && errv >= 0 && errv <= 0xFF && size <= 0xFF);
    }
    if (ok) {
        memcpy(p, &t, 8); /* little-endian host (x86-64), as "<d" */
        p[8] = (unsigned char)(idv & 0xFF);
        p[9] = (unsigned char)((idv >> 8) & 0xFF);
        p[10] = (unsigned char)errv;
        p[11] = (unsigned char)size;
        memset(p + 12, 0, RECORD_DATA);
        memcpy(p + 12, bytes, (size_t)(size < RECORD_DATA ? size : RECORD_DATA));
    }
    Py_XDECREF(ts);
    Py_XDECREF(id);
    Py_XDECREF(err);
    Py_XDECREF(data);
    return ok;
}

static PyObject *pack_records(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(1);
    PyObject *frames = args[0];
    if (!(PyList_CheckExact(frames) || PyTuple_CheckExact(frames))) Py_RETURN_NONE;
    Py_ssize_t count = PySequence_Fast_GET_SIZE(frames);
    PyObject *out = PyBytes_FromStringAndSize(NULL, count * RECORD_SIZE);
    if (out == NULL) return NULL;
    unsigned char *p = (unsigned char *)PyBytes_AS_STRING(out);
    for (Py_ssize_t k = 0; k < count; ++k, p += RECORD_SIZE) {
        if (!pack_record(PySequence_Fast_GET_ITEM(frames, k), p)) {
            Py_DECREF(out);
            Py_RETURN_NONE;
        }
    }
    return out;
}

/* ------------------------------------------------------------------ pack_records_append
 * pack_records_append(buffer, fallback, frames) -> None | fallback(frames): append the
 * records pack_records(frames) returns to the bytearray `buffer` (no bytes object per call,
 * no join); when a value does not fit that layout, nothing is appended and fallback(frames)
 * (which packs in Python and appends, or raises struct.error) is called instead. Bound with
 * functools.partial, it is FrameRecorder.add_many without a Python frame. */
static PyObject *pack_records_append(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(3);
    PyObject *buffer = args[0], *fallback = args[1], *frames = args[2];
    if (!PyByteArray_CheckExact(buffer)) {
        PyErr_SetString(PyExc_TypeError, "pack_records_append: buffer must be a bytearray");
        return NULL;
    }
    if (PyList_CheckExact(frames) || PyTuple_CheckExact(frames)) {
        Py_ssize_t count = PySequence_Fast_GET_SIZE(frames);
        Py_ssize_t start = PyByteArray_GET_SIZE(buffer);
        Py_ssize_t end = start + count * RECORD_SIZE;
        if (PyByteArray_Resize(buffer, end) < 0) return NULL;
        Py_ssize_t k = 0;
        for (; k < count; ++k) {
            /* the address is taken again per frame: a generic attribute read runs Python code */
            if (PyByteArray_GET_SIZE(buffer) != end) break;
            unsigned char *p = (unsigned char *)PyByteArray_AS_STRING(buffer) + start + k * RECORD_SIZE;
            if (!pack_record(PySequence_Fast_GET_ITEM(frames, k), p)) break;
        }
        if (k == count && PyByteArray_GET_SIZE(buffer) == end) Py_RETURN_NONE;
        if (PyByteArray_GET_SIZE(buffer) >= start && PyByteArray_Resize(buffer, start) < 0) return NULL;
    }
    return PyObject_CallOneArg(fallback, frames);
}

/* ------------------------------------------------------------------ module */

static PyMethodDef methods[] = {
    {"pack_preq", (PyCFunction)(void (*)(void))pack_preq, METH_FASTCALL, "Quantise, pack and stamp the PReqs."},
    {"latch_pres", (PyCFunction)(void (*)(void))latch_pres, METH_FASTCALL, "Quantise and pack the PRes payloads."},
    {"apply_due", (PyCFunction)(void (*)(void))apply_due, METH_FASTCALL, "Apply the set-points due at the SoC."},
    {"scale_into", (PyCFunction)(void (*)(void))scale_into, METH_FASTCALL, "Integers times scales into an array."},
    {"pres_frames", (PyCFunction)(void (*)(void))pres_frames, METH_FASTCALL, "Stamp and list the PRes frames."},
    {"receive_pres", (PyCFunction)(void (*)(void))receive_pres, METH_FASTCALL, "Digest TPDO1/TPDO2 frames."},
    {"receive_preq", (PyCFunction)(void (*)(void))receive_preq, METH_FASTCALL, "Digest RPDO1 frames."},
    {"pack_records", (PyCFunction)(void (*)(void))pack_records, METH_FASTCALL, "Recorder records of frames."},
    {"pack_records_append", (PyCFunction)(void (*)(void))pack_records_append, METH_FASTCALL,
     "Append recorder records of frames to a bytearray."},
    {"register_message_types", (PyCFunction)(void (*)(void))register_message_types, METH_FASTCALL,
     "Message types whose attributes are read and written at their slot offsets."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "fieldbus_codec",
                                    "Compiled per-node and per-frame work of fieldbus.nodes.", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit_fieldbus_codec(void)
{
    const unsigned short probe = 1;
    if (*(const unsigned char *)&probe != 1) {
        PyErr_SetString(PyExc_ImportError, "fieldbus_codec: little-endian hosts only");
        return NULL;
    }
    s_timestamp = PyUnicode_InternFromString("timestamp");
    s_data = PyUnicode_InternFromString("data");
    s_arbitration_id = PyUnicode_InternFromString("arbitration_id");
    s_is_error_frame = PyUnicode_InternFromString("is_error_frame");
    s_is_remote_frame = PyUnicode_InternFromString("is_remote_frame");
    s_is_extended_id = PyUnicode_InternFromString("is_extended_id");
    s_sync_seen = PyUnicode_InternFromString("_sync_seen");
    s_sync_ts = PyUnicode_InternFromString("_sync_ts");
    if (!s_timestamp || !s_data || !s_arbitration_id || !s_is_error_frame || !s_is_remote_frame || !s_is_extended_id ||
        !s_sync_seen || !s_sync_ts)
        return NULL;
    return PyModule_Create(&module);
}
