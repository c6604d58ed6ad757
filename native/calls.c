/* native_calls: call a compiled function at its address from Python, for the per-cycle calls
 * of the loop (the master's stepping kernel, the controller's compiled cycles).
 *
 * A ctypes foreign call converts every argument through its argtypes and builds the call
 * frame with libffi: about 5 000 instructions per call (callgrind). These functions take the
 * function's address and its arguments as Python integers (addresses, long long) and call it
 * directly, releasing the GIL around the call as ctypes does; the result is the function's int.
 * One entry per C signature:
 *
 *   int_p_ll_p(fn, p, k, q)        int fn(void *, long long, void *)
 *   int_p_p_p(fn, p, a, b)         int fn(void *, void *, void *)
 *   int_p_ll_ll_p(fn, p, a, b, q)  int fn(void *, long long, long long, void *)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

typedef int (*fn_p_ll_p)(void *, long long, void *);
typedef int (*fn_p_p_p)(void *, void *, void *);
typedef int (*fn_p_ll_ll_p)(void *, long long, long long, void *);

/* an address from a Python int (0 / None: NULL); -1 with an exception on error */
static int address(PyObject *o, void **out)
{
    if (o == Py_None) {
        *out = NULL;
        return 0;
    }
    *out = PyLong_AsVoidPtr(o);
    return (*out == NULL && PyErr_Occurred()) ? -1 : 0;
}

static int number(PyObject *o, long long *out)
{
    *out = PyLong_AsLongLong(o);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

#define CHECK_ARGS(count)                                                               \
    if (nargs != (count)) {                                                             \
        PyErr_Format(PyExc_TypeError, "expected %d arguments, got %zd", (count), nargs); \
        return NULL;                                                                    \
    }

static PyObject *int_p_ll_p(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(4);
    void *fn, *p, *q;
    long long k;
    if (address(args[0], &fn) || address(args[1], &p) || number(args[2], &k) || address(args[3], &q)) return NULL;
    if (fn == NULL) {
        PyErr_SetString(PyExc_ValueError, "int_p_ll_p: NULL function");
        return NULL;
    }
    int r;
    Py_BEGIN_ALLOW_THREADS
    r = ((fn_p_ll_p)fn)(p, k, q);
    Py_END_ALLOW_THREADS
    return PyLong_FromLong(r);
}

static PyObject *int_p_p_p(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(4);
    void *fn, *p, *a, *b;
    if (address(args[0], &fn) || address(args[1], &p) || address(args[2], &a) || address(args[3], &b)) return NULL;
    if (fn == NULL) {
        PyErr_SetString(PyExc_ValueError, "int_p_p_p: NULL function");
        return NULL;
    }
    int r;
    Py_BEGIN_ALLOW_THREADS
    r = ((fn_p_p_p)fn)(p, a, b);
    Py_END_ALLOW_THREADS
    return PyLong_FromLong(r);
}

static PyObject *int_p_ll_ll_p(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    CHECK_ARGS(5);
    void *fn, *p, *q;
    long long a, b;
    if (address(args[0], &fn) || address(args[1], &p) || number(args[2], &a) || number(args[3], &b) ||
        address(args[4], &q))
        return NULL;
    if (fn == NULL) {
        PyErr_SetString(PyExc_ValueError, "int_p_ll_ll_p: NULL function");
        return NULL;
    }
    int r;
    Py_BEGIN_ALLOW_THREADS
    r = ((fn_p_ll_ll_p)fn)(p, a, b, q);
    Py_END_ALLOW_THREADS
    return PyLong_FromLong(r);
}

static PyMethodDef methods[] = {
    {"int_p_ll_p", (PyCFunction)(void (*)(void))int_p_ll_p, METH_FASTCALL, "int fn(void *, long long, void *)"},
    {"int_p_p_p", (PyCFunction)(void (*)(void))int_p_p_p, METH_FASTCALL, "int fn(void *, void *, void *)"},
    {"int_p_ll_ll_p", (PyCFunction)(void (*)(void))int_p_ll_ll_p, METH_FASTCALL,
     "int fn(void *, long long, long long, void *)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "native_calls",
                                    "Direct calls of compiled functions by address.", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit_native_calls(void) { return PyModule_Create(&module); }
