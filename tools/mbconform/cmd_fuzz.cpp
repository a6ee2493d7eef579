// mbconform fuzz (being written).
#include "commands.h"

namespace mbc::cli {
void add_fuzz_command(CLI::App& app, int& exit_code) {}
}  // namespace mbc::cli
