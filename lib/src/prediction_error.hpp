// prediction_error.hpp: the prediction-error fit behind vibid_oe for stands with
// disturbances (vibid/output_error.h, "Stands with disturbances"; never installed).
#pragma once

#include <vibid/output_error.h>

#include <memory>
#include <string>
#include <vector>

namespace vibid {

class PredictionError {
public:
    // Throws vibid::Error for what the fit cannot take (a base, a cubic spring, no
    // disturbance, no measured response).
    PredictionError(const vibid_model &model, const vibid_oe_config &cfg);
    PredictionError(const PredictionError &other);
    ~PredictionError();

    std::size_t n_params() const;
    // Model channel of each response channel (the offsets' order).
    const std::vector<long> &response_channels() const;
    // As OutputError::fit (vibid_oe_fit).
    vibid_status fit(std::size_t n_samples, const double *channels, std::size_t n_starts, const double *starts);
    // As vibid_oe_result; x0 receives zeros (the predictor starts from the stationary mean).
    void result(double *theta, double *se, double *cov, double *offsets, double *offsets_se, double *x0,
                vibid_oe_fit_info *info) const;
    // The deterministic part (inputs only, no disturbance) as vibid_oe_simulate.
    void simulate(const double *theta, const double *x0, const double *offsets, std::size_t n_samples,
                  const double *channels, double *out);
    // As vibid_oe_predict.
    void predict(std::size_t n_samples, const double *channels, double *innovations, double *innovation_cov);
    // As vibid_oe_noise.
    void noise(double *dist_std, double *dist_se, double *chan_std, double *chan_se) const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace vibid
