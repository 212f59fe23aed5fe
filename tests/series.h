// Statistics of a sampled series, shared by the energy-conservation and thermostat tests.
#pragma once

#include <cmath>
#include <cstddef>
#include <numeric>
#include <vector>

namespace cftest {

// Least-squares slope of y against x.
inline double slope(const std::vector<double>& x, const std::vector<double>& y) {
  const double mx = std::accumulate(x.begin(), x.end(), 0.0) / double(x.size());
  const double my = std::accumulate(y.begin(), y.end(), 0.0) / double(y.size());
  double sxy = 0, sxx = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    sxy += (x[k] - mx) * (y[k] - my);
    sxx += (x[k] - mx) * (x[k] - mx);
  }
  return sxy / sxx;
}

// Root mean square of y about its mean.
inline double rms_about_mean(const std::vector<double>& y) {
  const double m = std::accumulate(y.begin(), y.end(), 0.0) / double(y.size());
  double s = 0;
  for (double v : y) s += (v - m) * (v - m);
  return std::sqrt(s / double(y.size()));
}

}  // namespace cftest
