#include "fascicle/core/error.hpp"

namespace fascicle {

Error::Error(ErrorKind kind, std::string message, ErrorContext context)
    : std::runtime_error(format(message, context)),
      kind_(kind),
      message_(std::move(message)),
      context_(std::move(context)) {}

ExitCode Error::exit_code() const {
  switch (kind_) {
    case ErrorKind::usage: return ExitCode::usage;
    case ErrorKind::bad_input: return ExitCode::bad_input;
    case ErrorKind::numerical: return ExitCode::numerical;
    case ErrorKind::internal: break;
  }
  return ExitCode::internal;
}

std::string Error::format(const std::string& message, const ErrorContext& c) {
  // "file:line: object 'x' at /json/path: message (hint: ...)"
  std::string out;
  if (!c.file.empty()) {
    out += c.file;
    if (c.line) out += ":" + std::to_string(*c.line);
    out += ": ";
  }
  if (!c.object.empty()) out += "'" + c.object + "': ";
  if (!c.json_path.empty()) out += "at " + c.json_path + ": ";
  out += message;
  if (!c.suggestion.empty()) out += " (" + c.suggestion + ")";
  return out;
}

Error Error::with_file(const std::string& file) const {
  ErrorContext c = context_;
  if (c.file.empty()) c.file = file;
  return Error(kind_, message_, c);
}

Error Error::with_object(const std::string& object) const {
  ErrorContext c = context_;
  if (c.object.empty()) c.object = object;
  return Error(kind_, message_, c);
}

void throw_bad_input(std::string message, ErrorContext context) {
  throw Error(ErrorKind::bad_input, std::move(message), std::move(context));
}
void throw_numerical(std::string message, ErrorContext context) {
  throw Error(ErrorKind::numerical, std::move(message), std::move(context));
}
void throw_usage(std::string message, ErrorContext context) {
  throw Error(ErrorKind::usage, std::move(message), std::move(context));
}
void throw_internal(std::string message, ErrorContext context) {
  throw Error(ErrorKind::internal, std::move(message), std::move(context));
}

}  // namespace fascicle
