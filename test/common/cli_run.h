// Running one of the command-line tools from a test: exit status, stdout and stderr.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace pcr_pro {
namespace test {

/// What a tool run gave back.
struct CliRun {
  int status = -1;  ///< exit status; 128 + N when killed by signal N
  std::string out, err;
};

/**
 * Runs `binary args` through the shell, with stdout and stderr captured in files of a temporary
 * directory of this process (`tag` names it, so that the tests of one binary do not share one).
 */
inline CliRun runCli(const std::string& binary, const std::string& args, const std::string& tag) {
  namespace fs = std::filesystem;
  const fs::path tmp = fs::temp_directory_path() / (tag + "_" + std::to_string(::getpid()));
  fs::create_directories(tmp);
  const std::string out = (tmp / "out.txt").string(), err = (tmp / "err.txt").string();
  const int raw = std::system((binary + " " + args + " >" + out + " 2>" + err).c_str());
  CliRun r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : 128 + WTERMSIG(raw);
  std::ifstream o(out), e(err);
  r.out.assign(std::istreambuf_iterator<char>(o), {});
  r.err.assign(std::istreambuf_iterator<char>(e), {});
  return r;
}

}  // namespace test
}  // namespace pcr_pro
