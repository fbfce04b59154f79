/* The tick's sleep: to an absolute deadline on CLOCK_MONOTONIC without the interpreter lock,
 * then take the lock back with a short switch interval (feeder/daemon/realtime.py).
 *
 * A thread that wants Python's lock waits one switch interval, then asks the holder to let
 * go; the holder hands it to whichever thread is waiting, so with several threads queued the
 * tick waits an interval per holder (0.5 ms each).  Python cannot shorten the interval for
 * that wait alone: it reads it when the wait starts, and the tick holds no lock to run Python
 * then.  This sets it between the wake-up and the wait, and restores it once the tick holds
 * the lock. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <errno.h>
#include <math.h>
#include <time.h>

/* CPython's own (sys.setswitchinterval); it only stores the value. */
PyAPI_FUNC(void) _PyEval_SetSwitchInterval(unsigned long microseconds);
PyAPI_FUNC(unsigned long) _PyEval_GetSwitchInterval(void);

static PyObject *sleep_until(PyObject *self, PyObject *args) {
    double deadline_s, urgent_s;
    if (!PyArg_ParseTuple(args, "dd:sleep_until", &deadline_s, &urgent_s)) return NULL;
    if (!isfinite(deadline_s) || !(urgent_s > 0 && urgent_s < 1)) {
        PyErr_SetString(PyExc_ValueError, "sleep_until: a finite deadline and 0 < urgent_s < 1");
        return NULL;
    }
    struct timespec at;
    double whole = floor(deadline_s);
    at.tv_sec = (time_t)whole;
    at.tv_nsec = (long)((deadline_s - whole) * 1e9);
    if (at.tv_nsec > 999999999L) at.tv_nsec = 999999999L;
    unsigned long normal = _PyEval_GetSwitchInterval();
    unsigned long urgent = (unsigned long)(urgent_s * 1e6);
    if (urgent < 1) urgent = 1;
    Py_BEGIN_ALLOW_THREADS
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, NULL) == EINTR) {
    }
    _PyEval_SetSwitchInterval(urgent);
    Py_END_ALLOW_THREADS
    _PyEval_SetSwitchInterval(normal);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"sleep_until", sleep_until, METH_VARARGS,
     "sleep_until(deadline_s, urgent_s): sleep to deadline_s (time.monotonic()) without the "
     "interpreter lock, then take it back with the switch interval at urgent_s (restored after)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_tick_wake", NULL, -1, methods};

PyMODINIT_FUNC PyInit__tick_wake(void) { return PyModule_Create(&module); }
