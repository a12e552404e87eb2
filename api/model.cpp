// spar::Model (include/spar/model.h): the packed file and its parsed configuration.
#include "api/api_impl.h"
#include "text/bpe_tokenizer.h"

namespace spar {

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
int64_t Model::imageHeight() const { return impl_->config.imageHeight; }
int64_t Model::imageWidth() const { return impl_->config.imageWidth; }
int64_t Model::patchSize() const { return impl_->config.patchSize; }
bool Model::semantic() const { return impl_->config.semanticDecoding(); }
bool Model::hasTokenizer() const { return impl_->file.has(BpeTokenizer::kPackedName); }
std::string Model::demonstrationNote() const {
  const auto& card = impl_->file.modelCard();
  return card ? modelCardSentence(*card) : std::string();
}

}  // namespace spar
