/* vibid/vibid.h: everything of the libvibid C API. See the individual headers for
 * units, shapes, ranges and ownership. */
#ifndef VIBID_VIBID_H
#define VIBID_VIBID_H
#include <vibid/common.h>
#include <vibid/lsq.h>
#include <vibid/rls.h>
#include <vibid/iv.h>
#endif
