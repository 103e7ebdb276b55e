// regressor_internal.hpp: what identify.cpp reads from a regressor beyond regressor.h.
#pragma once

#include <vibid/regressor.h>

namespace vibid {

// The value, in the last row vibid_regressor_push built, of a column that is 1 in every
// row before the pre-filter: the filter's step response since the last restart (1 without
// the filter). The regressor of a constant force: a constant in the data passes through
// the filter like every column, so the regression stays exact from the first row.
double regressor_unit(const vibid_regressor &reg);

}  // namespace vibid
