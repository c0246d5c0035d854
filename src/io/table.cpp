// Reading, writing and resampling of time-series tables (.mot, .sto, .csv).
#include "fascicle/io/table.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"

namespace fascicle {
namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::string_view trim(std::string_view s) {
  const auto not_space = [](char c) { return !std::isspace(static_cast<unsigned char>(c)); };
  const auto b = std::find_if(s.begin(), s.end(), not_space);
  const auto e = std::find_if(s.rbegin(), s.rend(), not_space).base();
  return b < e ? std::string_view(&*b, static_cast<std::size_t>(e - b)) : std::string_view();
}

// Splits on any of `seps`; with `collapse`, runs of separators count as one and empty fields at
// the ends are dropped (whitespace-separated numbers), otherwise every separator splits.
std::vector<std::string_view> split(std::string_view line, std::string_view seps, bool collapse) {
  std::vector<std::string_view> out;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= line.size(); ++i) {
    if (i == line.size() || seps.find(line[i]) != std::string_view::npos) {
      std::string_view field = line.substr(start, i - start);
      if (!collapse || !field.empty()) out.push_back(collapse ? field : trim(field));
      start = i + 1;
    }
  }
  return out;
}

struct Reader {
  std::filesystem::path path;
  std::vector<std::string> lines;  // without line ends

  [[noreturn]] void fail(long line_index, const std::string& message,
                         const std::string& suggestion = {}) const {
    throw_bad_input(message, ErrorContext{path.string(), line_index + 1, {}, {}, suggestion});
  }
};

Reader load_lines(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw_bad_input("cannot open the table file",
                    ErrorContext{path.string(), std::nullopt, {}, {}, "check the path"});
  Reader r{path, {}};
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    r.lines.push_back(std::move(line));
  }
  return r;
}

double parse_value(const Reader& r, long line_index, std::string_view field, long column,
                   const std::vector<std::string>& labels) {
  const std::string_view f = trim(field);
  double v = 0.0;
  const char* first = f.data();
  const char* last = f.data() + f.size();
  if (!f.empty() && *first == '+') ++first;
  const auto [ptr, ec] = std::from_chars(first, last, v);
  const std::string col_name = column == 0 ? std::string("time") : labels[column - 1];
  if (f.empty() || ec != std::errc() || ptr != last)
    r.fail(line_index, fmt::format("column {} ('{}'): cannot read '{}' as a number", column + 1,
                                   col_name, f));
  if (!std::isfinite(v))
    r.fail(line_index, fmt::format("column {} ('{}'): value '{}' is not finite", column + 1,
                                   col_name, f),
           "fill or remove the missing samples");
  return v;
}

// Reads the rows that follow the label line into the table.
void read_rows(const Reader& r, std::size_t first_row, std::string_view seps, bool collapse,
               Table& t) {
  const long ncols = t.columns() + 1;
  std::vector<double> values;
  std::vector<long> row_lines;
  for (std::size_t i = first_row; i < r.lines.size(); ++i) {
    if (trim(r.lines[i]).empty()) continue;
    const auto fields = split(r.lines[i], seps, collapse);
    if (static_cast<long>(fields.size()) != ncols)
      r.fail(static_cast<long>(i),
             fmt::format("row has {} values but the table has {} columns (time and {} labels)",
                         fields.size(), ncols, t.columns()));
    for (long c = 0; c < ncols; ++c)
      values.push_back(parse_value(r, static_cast<long>(i), fields[c], c, t.labels));
    row_lines.push_back(static_cast<long>(i));
  }
  const long nrows = static_cast<long>(row_lines.size());
  t.time.resize(nrows);
  t.data.resize(nrows, t.columns());
  for (long k = 0; k < nrows; ++k) {
    t.time[k] = values[k * ncols];
    for (long c = 1; c < ncols; ++c) t.data(k, c - 1) = values[k * ncols + c];
    if (k > 0 && !(t.time[k] > t.time[k - 1]))
      r.fail(row_lines[k],
             fmt::format("time {} does not increase (previous row has time {})", t.time[k],
                         t.time[k - 1]),
             "sort the rows by time and remove duplicate frames");
  }
}

void check_time_label(const Reader& r, long line_index, const std::vector<std::string>& labels) {
  if (labels.empty() || lower(labels.front()) != "time")
    r.fail(line_index,
           fmt::format("the first column must be 'time' (found '{}')",
                       labels.empty() ? std::string() : labels.front()));
}

Table read_sto(const Reader& r) {
  Table t;
  std::size_t i = 0;
  bool ended = false;
  for (; i < r.lines.size(); ++i) {
    const std::string_view line = trim(r.lines[i]);
    if (lower(line) == "endheader") {
      ended = true;
      ++i;
      break;
    }
    const auto eq = line.find('=');
    if (eq == std::string_view::npos) {
      if (i == 0) t.name = std::string(line);  // other free text is description, not kept
      continue;
    }
    const std::string key(trim(line.substr(0, eq)));
    const std::string value(trim(line.substr(eq + 1)));
    if (lower(key) == "indegrees") {
      const std::string v = lower(value);
      if (v != "yes" && v != "no")
        r.fail(static_cast<long>(i), fmt::format("inDegrees must be 'yes' or 'no', not '{}'", value));
      t.in_degrees = v == "yes";
    } else {
      t.header.emplace_back(key, value);
    }
  }
  if (!ended)
    r.fail(static_cast<long>(r.lines.size()) - 1, "no 'endheader' line found",
           "an OpenSim .mot/.sto header ends with a line 'endheader'");
  while (i < r.lines.size() && trim(r.lines[i]).empty()) ++i;
  if (i >= r.lines.size()) r.fail(static_cast<long>(i) - 1, "no column-label line after 'endheader'");
  // Labels are tab separated (they may contain spaces); old files separate them by spaces.
  const std::string& label_line = r.lines[i];
  const bool tabs = label_line.find('\t') != std::string::npos;
  std::vector<std::string> labels;
  for (auto f : split(label_line, tabs ? "\t" : " ", true))
    if (!trim(f).empty()) labels.emplace_back(trim(f));
  check_time_label(r, static_cast<long>(i), labels);
  t.labels.assign(labels.begin() + 1, labels.end());
  read_rows(r, i + 1, " \t", true, t);
  return t;
}

Table read_csv(const Reader& r) {
  Table t;
  std::size_t i = 0;
  while (i < r.lines.size() && (trim(r.lines[i]).empty() || trim(r.lines[i])[0] == '#')) ++i;
  if (i >= r.lines.size()) r.fail(0, "the CSV file has no label row");
  const std::string& label_line = r.lines[i];
  const std::string_view sep = label_line.find(',') != std::string::npos ? "," : ";";
  std::vector<std::string> labels;
  for (auto f : split(label_line, sep, false)) {
    std::string_view s = trim(f);
    if (s.size() >= 2 && s.front() == '"' && s.back() == '"') s = s.substr(1, s.size() - 2);
    labels.emplace_back(s);
  }
  check_time_label(r, static_cast<long>(i), labels);
  t.labels.assign(labels.begin() + 1, labels.end());
  t.name = r.path.stem().string();
  read_rows(r, i + 1, sep, false, t);
  return t;
}

std::string format_number(double v) { return fmt::format("{}", v); }

}  // namespace

Table read_table(const std::filesystem::path& path) {
  const Reader r = load_lines(path);
  const std::string ext = lower(path.extension().string());
  if (ext == ".csv") return read_csv(r);
  if (ext == ".mot" || ext == ".sto" || ext == ".txt") return read_sto(r);
  throw_usage(fmt::format("unknown table format '{}'", ext),
              ErrorContext{path.string(), std::nullopt, {}, {}, "use .mot, .sto or .csv"});
}

void write_sto(const std::filesystem::path& path, const Table& t) {
  write_file_atomically(path, [&](std::ostream& out) {
    out << (t.name.empty() ? path.stem().string() : t.name) << '\n';
    out << "version=1\n";
    out << "nRows=" << t.rows() << '\n';
    out << "nColumns=" << t.columns() + 1 << '\n';
    out << "inDegrees=" << (t.in_degrees ? "yes" : "no") << '\n';
    for (const auto& [key, value] : t.header) {
      const std::string k = lower(key);
      if (k == "version" || k == "nrows" || k == "ncolumns" || k == "indegrees") continue;
      out << key << '=' << value << '\n';
    }
    out << "endheader\ntime";
    for (const auto& l : t.labels) out << '\t' << l;
    out << '\n';
    for (long k = 0; k < t.rows(); ++k) {
      out << format_number(t.time[k]);
      for (long c = 0; c < t.columns(); ++c) out << '\t' << format_number(t.data(k, c));
      out << '\n';
    }
  });
}

void write_csv(const std::filesystem::path& path, const Table& t) {
  write_file_atomically(path, [&](std::ostream& out) {
    out << "time";
    for (const auto& l : t.labels) {
      if (l.find_first_of(",\"") != std::string::npos)
        throw_usage(fmt::format("label '{}' contains a comma or quote and cannot be written to CSV", l),
                    ErrorContext{path.string(), std::nullopt, {}, {}, "write a .sto instead"});
      out << ',' << l;
    }
    out << '\n';
    for (long k = 0; k < t.rows(); ++k) {
      out << format_number(t.time[k]);
      for (long c = 0; c < t.columns(); ++c) out << ',' << format_number(t.data(k, c));
      out << '\n';
    }
  });
}

long find_column(const Table& table, std::string_view label) {
  for (std::size_t i = 0; i < table.labels.size(); ++i)
    if (table.labels[i] == label) return static_cast<long>(i);
  return -1;
}

std::string find_coordinate_of_label(std::string_view label) {
  if (label.empty() || label.front() != '/') return std::string(label);
  const auto slash = label.rfind('/');
  const std::string_view last = label.substr(slash + 1);
  if (last != "value") return {};
  const std::string_view head = label.substr(0, slash);
  return std::string(head.substr(head.rfind('/') + 1));
}

VecX calc_row_at(const Table& t, double time) {
  if (t.rows() == 0) throw_bad_input("the table has no rows", ErrorContext{{}, {}, {}, t.name, {}});
  const long n = t.rows();
  if (time <= t.time[0]) return t.data.row(0).transpose();
  if (time >= t.time[n - 1]) return t.data.row(n - 1).transpose();
  const double* begin = t.time.data();
  const long hi = static_cast<long>(std::upper_bound(begin, begin + n, time) - begin);
  const long lo = hi - 1;
  const double s = (time - t.time[lo]) / (t.time[hi] - t.time[lo]);
  return ((1.0 - s) * t.data.row(lo) + s * t.data.row(hi)).transpose();
}

Table resample_linear(const Table& t, double frame_rate) {
  if (!(frame_rate > 0.0) || !std::isfinite(frame_rate))
    throw_usage(fmt::format("frame rate must be positive (got {})", frame_rate));
  if (t.rows() == 0) throw_bad_input("cannot resample a table with no rows",
                                     ErrorContext{{}, {}, {}, t.name, {}});
  const double t0 = t.time[0];
  const double t1 = t.time[t.rows() - 1];
  const long n = static_cast<long>(std::floor((t1 - t0) * frame_rate + 1e-9 * frame_rate)) + 1;
  Table out;
  out.name = t.name;
  out.labels = t.labels;
  out.in_degrees = t.in_degrees;
  out.header = t.header;
  out.time.resize(n);
  out.data.resize(n, t.columns());
  for (long k = 0; k < n; ++k) {
    out.time[k] = t0 + static_cast<double>(k) / frame_rate;
    out.data.row(k) = calc_row_at(t, out.time[k]).transpose();
  }
  return out;
}

}  // namespace fascicle
