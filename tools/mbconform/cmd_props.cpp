// mbconform props (being written).
#include "commands.h"

namespace mbc::cli {
void add_props_command(CLI::App& app, int& exit_code) {}
}  // namespace mbc::cli
