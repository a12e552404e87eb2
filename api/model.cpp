// spar::Model (include/spar/model.h): the packed file and its parsed configuration.
#include "api/api_impl.h"
#include "model/model_card.h"
#include "model/spar_pipeline.h"
#include "text/bpe_tokenizer.h"

namespace spar {
namespace {

int64_t configCount(const SparConfig& c, const char* key) {
  const auto it = c.raw.find(key);
  return it != c.raw.end() && it->is_number_integer() ? it->get<int64_t>() : 0;
}

}  // namespace

Model Model::open(const std::string& path) {
  PackedModel file = PackedModel::open(path);
  SparConfig config = SparConfig::fromJson(file.config(), file.path());
  return Model(std::make_unique<Impl>(Impl{std::move(file), std::move(config)}));
}

Model::Model(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Model::~Model() = default;
Model::Model(Model&&) noexcept = default;
Model& Model::operator=(Model&&) noexcept = default;

const std::string& Model::path() const { return impl_->file.path(); }
uint64_t Model::fileBytes() const { return impl_->file.fileBytes(); }
std::string Model::configJson() const { return impl_->file.config().dump(); }
int64_t Model::imageHeight() const { return impl_->config.imageHeight; }
int64_t Model::imageWidth() const { return impl_->config.imageWidth; }
int64_t Model::patchSize() const { return impl_->config.patchSize; }
// Every SPAR model has the image tokenizer's patch projection, and a pack stores all its
// matrices alike: that one says how.
std::string Model::matrixStorage() const { return fileDTypeName(impl_->file.info("image_tokenizer.1.weight").dtype); }
std::string Model::sizeProblem(int64_t height, int64_t width) const {
  return imageSizeProblem(impl_->config, height, width);
}
int64_t Model::trainingViews() const { return configCount(impl_->config, "num_views"); }
int64_t Model::trainingInputViews() const { return configCount(impl_->config, "num_input_views"); }
float Model::maskThreshold() const { return impl_->config.maskThreshold; }
bool Model::semantic() const { return impl_->config.semanticDecoding(); }
int64_t Model::featureChannels() const { return impl_->config.semanticDecoding() ? impl_->config.semanticDim : 0; }
bool Model::hasTokenizer() const { return impl_->file.has(BpeTokenizer::kPackedName); }
std::string Model::refinementProblem() const { return spar::refinementProblem(impl_->file); }

std::optional<DemonstrationNote> Model::demonstration() const {
  const auto& card = impl_->file.modelCard();
  if (!card) return std::nullopt;
  return DemonstrationNote{modelCardClaim(*card), kOfficialWeightsWhen, kOfficialWeightsAction, kOfficialWeightsDoc};
}

std::string Model::demonstrationNote() const {
  const auto note = demonstration();
  return note ? note->sentence() : std::string();
}

}  // namespace spar
