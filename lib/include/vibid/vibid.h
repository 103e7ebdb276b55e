/* vibid/vibid.h: everything of the libvibid C API. See the individual headers for
 * units, shapes, ranges and ownership. */
#ifndef VIBID_VIBID_H
#define VIBID_VIBID_H
#include <vibid/common.h>
#include <vibid/lsq.h>
#include <vibid/rls.h>
#include <vibid/iv.h>
#include <vibid/model.h>
#include <vibid/regressor.h>
#include <vibid/discretize.h>
#include <vibid/modal.h>
#include <vibid/identify.h>
#include <vibid/output_error.h>
#include <vibid/io_form.h>
#include <vibid/kf_rls.h>
#include <vibid/plausibility.h>
#include <vibid/report.h>
#include <vibid/simulate.h>
#include <vibid/oma.h>
#endif
