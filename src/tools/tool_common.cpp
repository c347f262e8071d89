#include "tool_common.h"

#include <algorithm>
#include <filesystem>
#include <new>
#include <fstream>
#include <iostream>

#include "pcr_pro/io/cloud_io.h"

namespace pcr_pro {
namespace tools {

Arguments::Arguments(int argc, char** argv, const std::set<std::string>& valued, const std::set<std::string>& flags) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (valued.count(arg)) {
      if (i + 1 >= argc) throw UsageError("option " + arg + " needs a value");
      if (values_.count(arg)) throw UsageError("option " + arg + " given twice");
      values_[arg] = argv[++i];
    } else if (flags.count(arg)) {
      flags_.insert(arg);
    } else {
      throw UsageError("unknown argument '" + arg + "' (see --help)");
    }
  }
}

std::optional<std::string> Arguments::value(const std::string& key) const {
  const auto it = values_.find(key);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::string Arguments::required(const std::string& key) const {
  const auto v = value(key);
  if (!v) throw UsageError("missing required option " + key + " (see --help)");
  return *v;
}

bool printedHelp(int argc, char** argv, const char* usage) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << usage;
      return true;
    }
  }
  return false;
}

std::uint64_t seedOption(const Arguments& args) {
  const auto text = args.value("--seed");
  if (!text) return kDefaultSeed;
  const bool digits = !text->empty() && text->size() <= 10 &&
                      std::all_of(text->begin(), text->end(), [](char c) { return c >= '0' && c <= '9'; });
  if (!digits || std::stoull(*text) > kMaxSeed) {
    throw UsageError("--seed: must be an integer in [0, " + std::to_string(kMaxSeed) + "], got '" + *text + "'");
  }
  return std::stoull(*text);
}

void writeOutputs(const std::string& dir, const std::string& yaml, const Cloud& fused) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw InputError(dir + ": cannot create output directory (" + ec.message() + ")");
  const std::string result_path = (std::filesystem::path(dir) / "result.yaml").string();
  std::ofstream out(result_path);
  out << yaml;
  if (!out) throw InputError(result_path + ": cannot write file");
  writePcd((std::filesystem::path(dir) / "fused.pcd").string(), fused);
}

int runTool(const char* tool, int argc, char** argv, int (*body)(int, char**)) {
  try {
    return body(argc, argv);
  } catch (const UsageError& e) {
    printError(tool, e.what());
  } catch (const InputError& e) {
    printError(tool, e.what());
  } catch (const std::bad_alloc&) {
    printError(tool, "out of memory (input too large?)");
  } catch (const std::exception& e) {
    printError(tool, std::string("error: ") + e.what());
  }
  return 2;
}

int exitStatus(const RegistrationReport& report) { return report.status == Status::kOk ? 0 : 1; }

void printError(const char* tool, const std::string& message) {
  constexpr std::size_t kMaxLength = 2000;
  std::string line = std::string(tool) + ": ";
  for (char c : message) {
    if (line.size() >= kMaxLength) {
      line += "...";
      break;
    }
    line += (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) ? ' ' : c;
  }
  std::cerr << line << "\n" << std::flush;
}

}  // namespace tools
}  // namespace pcr_pro
