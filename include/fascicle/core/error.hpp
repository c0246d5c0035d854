// The error type of fascicle: a kind (which maps to the CLI exit code), a message, and context
// (file, line or JSON path, object name) plus a suggestion of what to do.
#pragma once

#include <optional>
#include <stdexcept>
#include <string>

namespace fascicle {

// Process exit codes of the CLI (docs/cli.md).
enum class ExitCode : int {
  ok = 0,
  internal = 1,   // a bug in fascicle, or an unexpected system failure
  usage = 2,      // wrong command-line usage
  bad_input = 3,  // an input file or parameter is malformed, inconsistent or non-physical
  numerical = 4,  // a solver did not converge or produced a non-finite value
};

enum class ErrorKind { internal, usage, bad_input, numerical };

// Where an error happened, and what the user can do about it. All fields are optional.
struct ErrorContext {
  std::string file;         // path of the input file
  std::optional<long> line;  // 1-based line (text formats) or column index (tables)
  std::string json_path;    // e.g. "/muscles/2/attachments/origin/body"
  std::string object;       // e.g. muscle, body, mesh or coordinate name
  std::string suggestion;   // what to do about it
};

class Error : public std::runtime_error {
 public:
  Error(ErrorKind kind, std::string message, ErrorContext context = {});

  ErrorKind kind() const { return kind_; }
  const std::string& message() const { return message_; }
  const ErrorContext& context() const { return context_; }
  ExitCode exit_code() const;

  // Returns a copy with context fields filled in where still empty (inner context wins).
  Error with_file(const std::string& file) const;
  Error with_object(const std::string& object) const;

 private:
  static std::string format(const std::string& message, const ErrorContext& context);
  ErrorKind kind_;
  std::string message_;
  ErrorContext context_;
};

// Shorthands that read well at the throw site.
[[noreturn]] void throw_bad_input(std::string message, ErrorContext context = {});
[[noreturn]] void throw_numerical(std::string message, ErrorContext context = {});
[[noreturn]] void throw_usage(std::string message, ErrorContext context = {});
[[noreturn]] void throw_internal(std::string message, ErrorContext context = {});

}  // namespace fascicle
