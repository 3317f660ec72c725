/* The recursion x[j+1] = A x[j] + w[j], j = 0 .. N-2, for k right-hand sides at once:
 * x[j] and w[j] are n x k, row-major, stored one after another (N x n x k); x[0] is given.
 * The loop over the k columns is innermost and contiguous, so the compiler vectorises it;
 * numpy spends more on its two calls per step than on the step's n*n*k multiply-adds. */

void sysid_propagate(int N, int n, int k, const double *A, const double *W, double *X)
{
    const long nk = (long)n * k;
    for (int j = 0; j + 1 < N; ++j) {
        const double *x = X + j * nk;
        const double *w = W + j * nk;
        double *y = X + (j + 1) * nk;
        for (int r = 0; r < n; ++r) {
            double *yr = y + (long)r * k;
            const double *wr = w + (long)r * k;
            for (int c = 0; c < k; ++c)
                yr[c] = wr[c];
            for (int s = 0; s < n; ++s) {
                const double a = A[r * n + s];
                const double *xs = x + (long)s * k;
                for (int c = 0; c < k; ++c)
                    yr[c] += a * xs[c];
            }
        }
    }
}
