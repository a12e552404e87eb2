// Warnings of the `spar` command: input that is legal but likely a mistake. One line each on
// stderr ("spar: warning: ..."); the run goes on.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar {
struct SparConfig;
struct TokenizedPrompts;
}  // namespace spar

namespace spar::cli {

void warn(const std::string& message);
// The warnings warn() printed since the last call (a render's page lists its own).
std::vector<std::string> takeWarnings();

// An image much smaller than what the model runs at (under a quarter of a side): upscaled.
void warnIfTiny(const std::string& file, int width, int height, int modelWidth, int modelHeight);
// More views than the checkpoint's configuration was trained with (num_views), when it says.
void warnIfManyViews(const SparConfig& config, size_t views, size_t inputs);
// Prompts longer than CLIP's 77 tokens (cut there: the tokenizer's warnings), and more labels
// (`count`) than the palette's 20 well-separated colours.
void warnAboutPrompts(const TokenizedPrompts& prompts, size_t count);

}  // namespace spar::cli
