/* A program outside the project that uses the installed libvibid: checks that the
 * header and library versions agree and fits y = 2 + 3 t exactly. */
#include <vibid/vibid.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

int main(void) {
    if (strcmp(vibid_version_string(), VIBID_VERSION_STRING) != 0 || vibid_version() != VIBID_VERSION) {
        fprintf(stderr, "version mismatch: header %s, library %s\n", VIBID_VERSION_STRING, vibid_version_string());
        return 1;
    }
    double X[8], Y[4], theta[2];
    for (int k = 0; k < 4; ++k) {
        X[k] = 1.0;
        X[k + 4] = k;
        Y[k] = 2.0 + 3.0 * k;
    }
    vibid_lsq *lsq = vibid_lsq_create(2, 1);
    vibid_status s = lsq ? vibid_lsq_add_rows(lsq, 4, X, Y, NULL) : VIBID_E_NO_MEMORY;
    if (s == VIBID_OK) s = vibid_lsq_solve(lsq, theta, NULL);
    vibid_lsq_destroy(lsq);
    if (s != VIBID_OK || fabs(theta[0] - 2.0) > 1e-12 || fabs(theta[1] - 3.0) > 1e-12) {
        fprintf(stderr, "fit failed: %s\n", vibid_strerror(s));
        return 1;
    }
    printf("consumer ok: vibid %s, theta = [%g, %g]\n", vibid_version_string(), theta[0], theta[1]);
    return 0;
}
