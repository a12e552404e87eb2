// Warnings of the `spar` command: input that is legal but likely a mistake. One line each on
// stderr ("spar: warning: ..."); the run goes on.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar::cli {

void warn(const std::string& message);
// The warnings warn() printed since the last call (a render's page lists its own).
std::vector<std::string> takeWarnings();

// An image much smaller than what the model runs at (under a quarter of a side): upscaled.
void warnIfTiny(const std::string& file, int width, int height, int modelWidth, int modelHeight);
// More views than the model was trained with (Model::trainingViews; 0: it does not say).
void warnIfManyViews(int64_t trainingViews, size_t views, size_t inputs);
// Prompts longer than CLIP's 77 tokens (cut there: Model::promptWarnings), and more labels
// (`count`) than the palette's 20 well-separated colours.
void warnAboutPrompts(const std::vector<std::string>& promptWarnings, size_t count);

}  // namespace spar::cli
