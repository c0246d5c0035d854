// Helpers shared by the test programs: where the real data lives, and scratch folders.
#pragma once

#include <filesystem>
#include <string>

namespace fascicle::test {

// The shared real-data folder (../shared/data beside the repository, or $FASCICLE_DATA_DIR).
std::filesystem::path data_dir();

// A file or folder below data_dir(). The calling test fails (fatally, with the path and what to do)
// when it is missing: tests that need real data never pass silently without it.
std::filesystem::path data_path(const std::string& relative);

// A file of this repository (e.g. "examples/vh_shank/scene.json"); fails the test clearly when it
// does not exist.
std::filesystem::path source_path(const std::string& relative);

// A readable parameterised-test name: the stem of `text` (a file path or name) with every
// character other than a letter or digit replaced by '_', then '_' and the case index.
std::string make_test_name(const std::string& text, std::size_t index);

// A plain HTTP/1.0 GET to 127.0.0.1:port with `raw_path` sent exactly as given (no
// normalisation, for traversal tests). Returns the status code (-1 when nothing answers) and,
// when `body` is given, the response body.
int http_get(int port, const std::string& raw_path, std::string* body = nullptr);

// Runs a shell command and captures its standard output (append " 2>&1" to the command to
// capture standard error too). exit_code is -1 when the command did not exit normally.
struct CommandResult {
  int exit_code;
  std::string output;
};
CommandResult run_command(const std::string& command);

// A fresh, empty folder under the system temporary directory, unique to this test.
std::filesystem::path scratch_dir(const std::string& name);

}  // namespace fascicle::test
