// ParaView time series: a .pvd collection file listing one dataset file per (time step, part).
// ParaView opens the .pvd and animates the parts over time. The .pvd is rewritten atomically
// after each frame, so a run that stops early still leaves a valid series of the frames written.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace fascicle {

// One dataset of the collection: `file` is relative to the .pvd's folder (forward slashes).
struct PvdDataSet {
  double time_s = 0.0;
  int part = 0;          // one part per object (bone, muscle surface, fibres, action line)
  std::string name;      // object name, written as the `name` attribute (ParaView shows it)
  std::string file;
};

// Writes a VTKFile of type "Collection" atomically. Throws fascicle::Error (bad_input) when the
// folder is not writable.
void write_pvd(const std::filesystem::path& path, const std::vector<PvdDataSet>& datasets);

// Reads the datasets of a .pvd (pugixml). Throws fascicle::Error (bad_input naming the file) for
// a missing file, malformed XML or a file that is not a VTK Collection.
std::vector<PvdDataSet> read_pvd(const std::filesystem::path& path);

// Incrementally built series: add the files of a frame, then commit() rewrites the .pvd.
class VtkSeriesWriter {
 public:
  explicit VtkSeriesWriter(std::filesystem::path pvd_path);

  const std::filesystem::path& get_pvd_path() const { return pvd_path_; }
  std::filesystem::path get_folder() const { return pvd_path_.parent_path(); }

  // Registers an object name once; returns its part index (stable over frames).
  int find_or_add_part(const std::string& name);

  // Adds a dataset (already written by the caller) to the collection in memory.
  void add(double time_s, int part, const std::string& relative_file);

  // Rewrites the .pvd with every dataset added so far (the same bytes as write_pvd; the text of
  // the datasets already written is kept, so a commit costs the new datasets plus the write).
  void commit() const;

  const std::vector<PvdDataSet>& get_datasets() const { return datasets_; }

 private:
  std::filesystem::path pvd_path_;
  std::vector<std::string> parts_;
  std::vector<PvdDataSet> datasets_;
  // commit()'s text: pugixml's lines before and after the datasets, and the datasets printed so far
  mutable std::string head_, tail_, body_;
  mutable std::size_t printed_ = 0;
};

}  // namespace fascicle
