// Voxel thinning (fmcwlog/kernels/voxel.py): the first point, in the order given, of each square
// voxel floor(xy / size) (voxel_downsample: exactly its points and order), or each voxel's centroid
// (voxel_centroids: the same sums in the same order, hence the same floats).
#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

// numpy's floor(v).astype(int64) on x86: a value outside int64's range, or NaN, becomes INT64_MIN.
// Truncation, one less for a negative non-integer: floor without a call into libm (the x86-64
// baseline has no rounding instruction).
inline int64_t floor_to_int64(double v) {
    if (!(v >= -9223372036854775808.0 && v < 9223372036854775808.0)) return std::numeric_limits<int64_t>::min();
    const int64_t i = int64_t(v);
    return double(i) > v ? i - 1 : i;
}

// voxel.voxel_keys of one point: (i << 32) ^ (j & 0xFFFFFFFF), i and j the voxel's int64 indices
inline uint64_t voxel_key(double x, double y, double size) {
    const uint64_t i = uint64_t(floor_to_int64(x / size)), j = uint64_t(floor_to_int64(y / size));
    return (i << 32) ^ (j & 0xFFFFFFFFull);
}

// An open-addressing set of keys (linear probing, a power-of-two table at least twice the points).
class KeySet {
  public:
    explicit KeySet(size_t n) {
        size_t cap = 16;
        while (cap < 2 * n) cap <<= 1;
        keys_.assign(cap, 0);
        used_.assign(cap, 0);
        mask_ = cap - 1;
    }
    // Whether the key was new (it is in the set afterwards either way).
    bool insert(uint64_t key) {
        uint64_t h = key * 0x9E3779B97F4A7C15ull;
        size_t at = size_t(h ^ (h >> 29)) & mask_;
        while (used_[at]) {
            if (keys_[at] == key) return false;
            at = (at + 1) & mask_;
        }
        used_[at] = 1;
        keys_[at] = key;
        return true;
    }

  private:
    std::vector<uint64_t> keys_;
    std::vector<uint8_t> used_;
    size_t mask_ = 0;
};

// voxel.voxel_downsample for size > 0 and N > 0: the kept points (M, 2), in the order given
// (np.unique's first index of each key, sorted).
nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> voxel_downsample(Points xy, double size) {
    const double* p = xy.data();
    const size_t n = xy.shape(0);
    std::vector<int64_t> keep;
    {
        nb::gil_scoped_release release;
        KeySet seen(n);
        keep.reserve(n);
        for (size_t i = 0; i < n; ++i)
            if (seen.insert(voxel_key(p[2 * i], p[2 * i + 1], size))) keep.push_back(int64_t(i));
    }
    double* out = new double[2 * keep.size() + 1];
    for (size_t k = 0; k < keep.size(); ++k) {
        out[2 * k] = p[2 * size_t(keep[k])];
        out[2 * k + 1] = p[2 * size_t(keep[k]) + 1];
    }
    nb::capsule owner(out, [](void* d) noexcept { delete[] static_cast<double*>(d); });
    return nb::ndarray<nb::numpy, double, nb::shape<-1, 2>>(out, {keep.size(), 2}, owner);
}

// An open-addressing map from key to slot (the order of first appearance), as KeySet.
class KeySlots {
  public:
    explicit KeySlots(size_t n) {
        size_t cap = 16;
        while (cap < 2 * n) cap <<= 1;
        keys_.assign(cap, 0);
        slot_.assign(cap, -1);
        mask_ = cap - 1;
    }
    // The key's slot, a new one (== size before the call) where the key is new.
    int64_t slot(uint64_t key) {
        uint64_t h = key * 0x9E3779B97F4A7C15ull;
        size_t at = size_t(h ^ (h >> 29)) & mask_;
        while (slot_[at] >= 0) {
            if (keys_[at] == key) return slot_[at];
            at = (at + 1) & mask_;
        }
        keys_[at] = key;
        slot_[at] = size_++;
        return slot_[at];
    }
    int64_t size() const { return size_; }

  private:
    std::vector<uint64_t> keys_;
    std::vector<int64_t> slot_;
    size_t mask_ = 0;
    int64_t size_ = 0;
};

// voxel.voxel_centroids_numpy for size > 0 and N > 0: each voxel's mean (M, 2), in the order of
// its first point; the sums run in the order given (np.bincount's), then one division each.
nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> voxel_centroids(Points xy, double size) {
    const double* p = xy.data();
    const size_t n = xy.shape(0);
    std::vector<double> sum;
    std::vector<int64_t> count;
    {
        nb::gil_scoped_release release;
        KeySlots slots(n);
        sum.reserve(2 * n);
        count.reserve(n);
        for (size_t i = 0; i < n; ++i) {
            const int64_t s = slots.slot(voxel_key(p[2 * i], p[2 * i + 1], size));
            if (s == int64_t(count.size())) {
                sum.push_back(0.0);
                sum.push_back(0.0);
                count.push_back(0);
            }
            sum[2 * size_t(s)] += p[2 * i];
            sum[2 * size_t(s) + 1] += p[2 * i + 1];
            ++count[size_t(s)];
        }
    }
    const size_t m = count.size();
    double* out = new double[2 * m + 1];
    for (size_t k = 0; k < m; ++k) {
        out[2 * k] = sum[2 * k] / double(count[k]);
        out[2 * k + 1] = sum[2 * k + 1] / double(count[k]);
    }
    nb::capsule owner(out, [](void* d) noexcept { delete[] static_cast<double*>(d); });
    return nb::ndarray<nb::numpy, double, nb::shape<-1, 2>>(out, {m, 2}, owner);
}

}  // namespace

void bind_voxel(nb::module_& m) {
    m.def("voxel_downsample", &voxel_downsample, nb::arg("xy"), nb::arg("size"));
    m.def("voxel_centroids", &voxel_centroids, nb::arg("xy"), nb::arg("size"));
}

}  // namespace fmcwlog
