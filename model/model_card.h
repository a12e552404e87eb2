// The model card of a packed model (`__metadata__.model_card`, converter/FORMAT.md; written by
// spar-convert --model-card, converter/spar_convert/model_card.py): what the model is, said to
// its users in one sentence so that a demonstration model's renders are not taken for the engine's
// limits. `spar render` prints the sentence once and its index.html opens with it.
#pragma once
#include <cstdint>
#include <optional>
#include <string>

namespace spar {

struct ModelCard {
  std::string kind;   // "demonstration" (the one kind so far)
  std::string about;  // what it is, a clause ("trained on ... for 58 minutes on procedural rooms, it renders ...")
  // What it measured, if the card says: PSNR on `what` against a baseline's.
  bool measured = false;
  std::string what, baseline;  // "held-out K=3", "copying the nearest input"
  double psnrDb = 0, baselinePsnrDb = 0;
  // How it was made, if the card says (its optional `training` record): what it was trained or
  // fitted on, its steps and minutes.
  bool trained = false;
  std::string trainingData;
  int64_t trainingSteps = 0;
  double trainingMinutes = 0;
};

// The card of the metadata value `text`, checked as the converter checks it; throws spar::Error
// "model_card: ..." naming the field that is wrong (PackedModel::open adds the file).
ModelCard parseModelCard(const std::string& text);

// Where the sentence points a user who wants real renders: "for real photos, convert the official
// checkpoint (docs/checkpoints.md)"; the page links the action to its own section on it.
inline constexpr const char* kOfficialWeightsWhen = "for real photos, ";
inline constexpr const char* kOfficialWeightsAction = "convert the official checkpoint";
inline constexpr const char* kOfficialWeightsDoc = "docs/checkpoints.md";

// "Demonstration model: <about> (<what> PSNR 18.1 dB, below the 20.0 dB of <baseline>)": the
// claim, without the pointer.
std::string modelCardClaim(const ModelCard& card);
// The whole sentence: the claim, then "; for real photos, convert the official checkpoint
// (docs/checkpoints.md)."
std::string modelCardSentence(const ModelCard& card);

}  // namespace spar
