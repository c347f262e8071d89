// pcr_pro_params: prints the parameter tables of the configuration files and of the node from the stages' schemas
// (include/pcr_pro/io/param_schema.h), or writes them into the README's generated sections.
#include <fstream>
#include <iostream>
#include <sstream>

#include "pcr_pro/merge/parameter_tables.h"
#include "pcr_pro/ros/node_options.h"
#include "tool_common.h"

namespace {

const char* kUsage =
    "usage: pcr_pro_params [--update FILE] [--help]\n"
    "Prints every parameter of the configuration files and of the merge node (key, type, default, range, unit, description) as\n"
    "Markdown tables, each between its section lines <!-- params:NAME --> and <!-- /params:NAME -->.\n"
    "--update FILE rewrites those sections of FILE (the README) in place.\n"
    "Exit: 0 OK, 2 bad input.\n";

int run(int argc, char** argv) {
  using namespace pcr_pro;
  const tools::Arguments args(argc, argv, {"--update"}, {"--help"});
  if (args.flag("--help")) {
    std::cout << kUsage;
    return 0;
  }
  auto tables = configParameterTables();
  tables.emplace_back("node", ros_bridge::nodeParameterTable());
  const auto file = args.value("--update");
  if (!file) {
    for (const auto& [name, body] : tables) {
      std::cout << "<!-- params:" << name << " -->\n" << body << "<!-- /params:" << name << " -->\n\n";
    }
    return 0;
  }
  std::ifstream in(*file);
  if (!in) throw InputError(*file + ": cannot open");
  std::stringstream text;
  text << in.rdbuf();
  const std::string updated = withParameterTables(text.str(), tables);
  std::ofstream out(*file);
  if (!(out << updated)) throw InputError(*file + ": cannot write");
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return pcr_pro::tools::runTool("pcr_pro_params", argc, argv, run); }
