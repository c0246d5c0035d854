#include "test_support.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <algorithm>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

namespace fascicle::test {

std::filesystem::path data_dir() {
  if (const char* env = std::getenv("FASCICLE_DATA_DIR"); env != nullptr && *env != '\0') {
    return std::filesystem::path(env);
  }
  return std::filesystem::path(FASCICLE_DEFAULT_DATA_DIR);
}

std::filesystem::path data_path(const std::string& relative) {
  const std::filesystem::path p = data_dir() / relative;
  if (!std::filesystem::exists(p)) {
    // GoogleTest's fatal assertions only work in void functions, so throw: gtest reports the
    // message as a failure of the running test.
    throw std::runtime_error("real data missing: " + p.string() +
                             " (tests read ../shared/data beside the repository; set "
                             "FASCICLE_DATA_DIR to its location)");
  }
  return p;
}

std::filesystem::path source_path(const std::string& relative) {
  const std::filesystem::path p = std::filesystem::path(FASCICLE_SOURCE_DIR) / relative;
  if (!std::filesystem::exists(p)) throw std::runtime_error("repository file missing: " + p.string());
  return p;
}

std::string make_test_name(const std::string& text, std::size_t index) {
  std::string name = std::filesystem::path(text).stem().string();
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name + "_" + std::to_string(index);
}

int http_get(int port, const std::string& raw_path, std::string* body) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return -1;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return -1;
  }
  const std::string req = "GET " + raw_path + " HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n";
  (void)!::write(fd, req.data(), req.size());
  std::string resp;
  char buf[65536];
  for (ssize_t n; (n = ::read(fd, buf, sizeof buf)) > 0;) resp.append(buf, static_cast<std::size_t>(n));
  ::close(fd);
  if (body) *body = resp.substr(std::min(resp.size(), resp.find("\r\n\r\n") + 4));
  return resp.size() > 12 ? std::stoi(resp.substr(9, 3)) : -1;
}

CommandResult run_command(const std::string& command) {
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return {-1, ""};
  std::string out;
  std::array<char, 4096> buf{};
  while (std::size_t n = std::fread(buf.data(), 1, buf.size(), pipe)) out.append(buf.data(), n);
  const int status = pclose(pipe);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out};
}

std::filesystem::path scratch_dir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string leaf = name;
  if (info != nullptr) {
    leaf = std::string(info->test_suite_name()) + "." + info->name() + "." + name;
  }
  const std::filesystem::path p = std::filesystem::temp_directory_path() /
                                  ("fascicle-test-" + std::to_string(::getpid())) / leaf;
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p;
}

}  // namespace fascicle::test
