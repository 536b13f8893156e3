/* Model-agnostic recurrence driver for CasADi-generated step functions (ident/chain.py).
 *
 * fn has the CasADi C API signature and inputs (s, w, theta, pfix), outputs (s_next, y_1, ..., y_m), all
 * dense. mt_chain runs s_{k+1} = fn(s_k, W[:, k], theta, pfix) for k = 0..n-1 and writes output j of
 * sample k to out[j] + k * out_size[j] (row k of an n x out_size[j] row-major array).
 * Returns 0, or 1 + k when fn failed at sample k, or -1 when memory ran out.
 */
#include <stdlib.h>
#include <string.h>

typedef long long int mt_int;
typedef int (*mt_fn)(const double **arg, double **res, mt_int *iw, double *w, int mem);

int mt_chain(mt_fn fn, long n, int ns, const double *s0, const double *W, int nw, const double *theta,
             const double *pfix, int n_out, const int *out_size, double **out,
             long sz_arg, long sz_res, long sz_iw, long sz_w)
{
    const double **arg = calloc((size_t)(sz_arg > 4 ? sz_arg : 4), sizeof *arg);
    double **res = calloc((size_t)(sz_res > n_out + 1 ? sz_res : n_out + 1), sizeof *res);
    mt_int *iw = malloc((size_t)(sz_iw > 0 ? sz_iw : 1) * sizeof *iw);
    double *w = malloc((size_t)(sz_w > 0 ? sz_w : 1) * sizeof *w);
    double *state = malloc((size_t)(2 * ns > 0 ? 2 * ns : 1) * sizeof *state);
    int status = 0;
    if (!arg || !res || !iw || !w || !state) {
        status = -1;
    } else {
        double *cur = state, *next = state + ns, *tmp;
        if (ns) memcpy(cur, s0, (size_t)ns * sizeof *cur);
        for (long k = 0; k < n; ++k) {
            arg[0] = cur;
            arg[1] = W + k * nw;
            arg[2] = theta;
            arg[3] = pfix;
            res[0] = next;
            for (int j = 0; j < n_out; ++j) res[j + 1] = out[j] + k * out_size[j];
            if (fn(arg, res, iw, w, 0)) {
                status = (int)(k + 1);
                break;
            }
            tmp = cur;
            cur = next;
            next = tmp;
        }
    }
    free(arg);
    free(res);
    free(iw);
    free(w);
    free(state);
    return status;
}
