// Time-series tables: OpenSim motion and storage files (.mot, .sto) and CSV. A Table holds one
// time column and any number of named data columns (rows = frames). Values are kept exactly as
// read: rotational columns of a file with `inDegrees=yes` stay in degrees until the caller, who
// knows which columns are angles (the skeleton), converts them.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "fascicle/core/types.hpp"

namespace fascicle {

struct Table {
  std::string name;                 // first header line of .mot/.sto (e.g. "Coordinates")
  std::vector<std::string> labels;  // data column labels, the time column excluded
  VecX time;                        // s, #frames, strictly increasing
  MatX data;                        // #frames × #labels
  bool in_degrees = false;          // header `inDegrees=yes`: angle columns are in degrees
  // Other `key=value` header lines in file order (version, nRows, DataType, ...).
  std::vector<std::pair<std::string, std::string>> header;

  long rows() const { return static_cast<long>(time.size()); }
  long columns() const { return static_cast<long>(labels.size()); }
};

// Reads an OpenSim .mot/.sto (format versions 1 and 3: a header ending in `endheader`, then a
// line of column labels whose first is `time`, then rows separated by tabs or spaces) or a .csv
// (first row labels, the first of which is `time`; separators `,` or `;`). The format follows the
// extension; `.txt` is read as .sto. Throws fascicle::Error (bad_input) naming the file, line and
// column for: a missing file, a missing header end or label line, a row with the wrong number of
// values, an unparsable or non-finite value, or time that is not strictly increasing.
Table read_table(const std::filesystem::path& path);

// Writes an OpenSim 4 style .sto/.mot (name, version=1, nRows, nColumns, inDegrees, the table's
// other header entries, endheader, tab-separated rows) or a CSV, atomically. Numbers are written
// in the shortest form that reads back to the same double.
void write_sto(const std::filesystem::path& path, const Table& table);
void write_csv(const std::filesystem::path& path, const Table& table);

// Index of the column whose label is exactly `label`, or -1.
long find_column(const Table& table, std::string_view label);

// The coordinate a column addresses: the label itself, or for an absolute OpenSim path such as
// `/jointset/knee_r/knee_angle_r/value` the component before `/value` ("knee_angle_r"). Labels
// ending in `/speed` (or any other output) give an empty string: they are not coordinate values.
std::string find_coordinate_of_label(std::string_view label);

// The row at time t, interpolated linearly between the two neighbouring frames (clamped to the
// first/last frame outside the time range). Returns #labels values.
VecX calc_row_at(const Table& table, double t);

// The table resampled at `frame_rate` (Hz) from its first time up to its last (the last time is
// included when it falls on the grid within 1e-9 s), by linear interpolation. Throws a usage error
// for a non-positive rate and a bad-input error for a table with no rows.
Table resample_linear(const Table& table, double frame_rate);

}  // namespace fascicle
