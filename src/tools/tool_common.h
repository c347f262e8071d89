// Helpers shared by the offline command-line tools (argument parsing, output writing).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>

#include "pcr_pro/io/report.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace tools {

/// Bad command line: reported as a one-line error and exit status 2.
class UsageError : public std::runtime_error {
 public:
  explicit UsageError(const std::string& m) : std::runtime_error(m) {}
};

/// Parses "--key value" options and "--flag" flags; throws UsageError on unknown or repeated
/// options and on options missing their value.
class Arguments {
 public:
  Arguments(int argc, char** argv, const std::set<std::string>& valued, const std::set<std::string>& flags);
  std::optional<std::string> value(const std::string& key) const;
  std::string required(const std::string& key) const;
  bool flag(const std::string& key) const { return flags_.count(key) > 0; }

 private:
  std::map<std::string, std::string> values_;
  std::set<std::string> flags_;
};

/// @return true, after printing `usage` on stdout, when an argument is --help or -h (the tool
/// then exits 0 whatever else the command line holds)
bool printedHelp(int argc, char** argv, const char* usage);

/// Largest seed the tools and the node accept (the node's `~seed` is an XML-RPC int).
constexpr std::uint64_t kMaxSeed = 2147483647;

/// @return the value of `--seed` (0 ... kMaxSeed), or kDefaultSeed when absent.
/// @throw UsageError naming the option when it is not such an integer
std::uint64_t seedOption(const Arguments& args);

/// Writes DIR/result.yaml and DIR/fused.pcd (creating DIR). @throw InputError on failure.
void writeOutputs(const std::string& dir, const std::string& yaml, const Cloud& fused);

/// @return exit status of the contract for a report: 0 when OK, 1 otherwise
int exitStatus(const RegistrationReport& report);

/// Prints "<tool>: <message>" as exactly one line on stderr: control characters (from file names
/// or file contents quoted in the message) become spaces, and the length is bounded.
void printError(const char* tool, const std::string& message);

/// Runs a tool's body and turns every exception into the contract's exit status 2 with a
/// one-line error (usage, input, out of memory, anything else); @return the body's status.
int runTool(const char* tool, int argc, char** argv, int (*body)(int, char**));

}  // namespace tools
}  // namespace pcr_pro
