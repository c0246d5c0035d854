// ParaView .pvd collection files (written and read with pugixml).
#include "fascicle/io/vtk_series.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"

#include <pugixml.hpp>

#include <algorithm>
#include <sstream>

namespace fascicle {

namespace {

// The collection document with the given datasets (pugixml).
pugi::xml_document make_pvd_document(const std::vector<PvdDataSet>& datasets) {
  pugi::xml_document doc;
  auto decl = doc.append_child(pugi::node_declaration);
  decl.append_attribute("version") = "1.0";
  auto root = doc.append_child("VTKFile");
  root.append_attribute("type") = "Collection";
  root.append_attribute("version") = "0.1";
  root.append_attribute("byte_order") = "LittleEndian";
  auto collection = root.append_child("Collection");
  for (const auto& d : datasets) {
    auto node = collection.append_child("DataSet");
    std::ostringstream t;
    t.precision(17);
    t << d.time_s;
    node.append_attribute("timestep") = t.str().c_str();
    node.append_attribute("group") = "";
    node.append_attribute("part") = d.part;
    node.append_attribute("name") = d.name.c_str();
    node.append_attribute("file") = d.file.c_str();
  }
  return doc;
}

constexpr const char* kIndent = "  ";

}  // namespace

void write_pvd(const std::filesystem::path& path, const std::vector<PvdDataSet>& datasets) {
  const pugi::xml_document doc = make_pvd_document(datasets);
  write_file_atomically(path, [&](std::ostream& out) { doc.save(out, kIndent); });
}

std::vector<PvdDataSet> read_pvd(const std::filesystem::path& path) {
  pugi::xml_document doc;
  const auto result = doc.load_file(path.c_str());
  if (!result) {
    throw_bad_input(std::string("cannot read the .pvd file: ") + result.description(),
                    {.file = path.string()});
  }
  auto root = doc.child("VTKFile");
  if (!root || std::string(root.attribute("type").as_string()) != "Collection")
    throw_bad_input("not a VTK Collection (.pvd) file", {.file = path.string()});
  std::vector<PvdDataSet> out;
  for (auto node : root.child("Collection").children("DataSet")) {
    PvdDataSet d;
    d.time_s = node.attribute("timestep").as_double();
    d.part = node.attribute("part").as_int();
    d.name = node.attribute("name").as_string();
    d.file = node.attribute("file").as_string();
    out.push_back(std::move(d));
  }
  return out;
}

VtkSeriesWriter::VtkSeriesWriter(std::filesystem::path pvd_path) : pvd_path_(std::move(pvd_path)) {}

int VtkSeriesWriter::find_or_add_part(const std::string& name) {
  const auto it = std::find(parts_.begin(), parts_.end(), name);
  if (it != parts_.end()) return static_cast<int>(it - parts_.begin());
  parts_.push_back(name);
  return static_cast<int>(parts_.size()) - 1;
}

void VtkSeriesWriter::add(double time_s, int part, const std::string& relative_file) {
  if (part < 0 || part >= static_cast<int>(parts_.size()))
    throw_internal("VtkSeriesWriter::add: unknown part " + std::to_string(part));
  datasets_.push_back({time_s, part, parts_[part], relative_file});
}

// The .pvd as write_pvd() formats it, without rebuilding and reformatting every dataset of the
// earlier frames at each commit (that grew with the square of the frame count: ≈ 0.12 s for 100
// frames of 22 files): the DataSet elements added since the last commit are printed by pugixml at
// their depth in the document and appended to the text of the earlier ones; the text around them
// is pugixml's own, taken once from a document holding one DataSet.
void VtkSeriesWriter::commit() const {
  if (datasets_.empty()) {  // pugixml writes an empty Collection as one element
    write_pvd(pvd_path_, datasets_);
    return;
  }
  if (head_.empty()) {
    const pugi::xml_document doc = make_pvd_document({PvdDataSet{}});
    std::ostringstream whole, one;
    doc.save(whole, kIndent);
    doc.child("VTKFile").child("Collection").first_child().print(one, kIndent, pugi::format_default,
                                                                  pugi::encoding_auto, 2);
    const std::string text = whole.str();
    const std::size_t at = text.find(one.str());
    if (at == std::string::npos) throw_internal("VtkSeriesWriter: unexpected .pvd layout");
    head_ = text.substr(0, at);
    tail_ = text.substr(at + one.str().size());
  }
  if (printed_ < datasets_.size()) {
    const std::vector<PvdDataSet> added(datasets_.begin() + static_cast<std::ptrdiff_t>(printed_), datasets_.end());
    const pugi::xml_document doc = make_pvd_document(added);
    std::ostringstream text;
    for (const auto node : doc.child("VTKFile").child("Collection").children())
      node.print(text, kIndent, pugi::format_default, pugi::encoding_auto, 2);
    body_ += text.str();
    printed_ = datasets_.size();
  }
  write_file_atomically(pvd_path_, [&](std::ostream& out) { out << head_ << body_ << tail_; });
}

}  // namespace fascicle
