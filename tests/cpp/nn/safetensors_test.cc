#include "nn/safetensors.h"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <string>

#include "test_files.h"

namespace m3c::nn {
namespace {

using testing::TempFile;

// Builds a file byte by byte from the documented layout, independently of the library's writer.
std::string HandMade(const std::string& header, const std::string& data) {
  std::string padded = header;
  while (padded.size() % 8) padded += ' ';
  const uint64_t n = padded.size();
  std::string out(8, '\0');
  std::memcpy(out.data(), &n, 8);
  return out + padded + data;
}

template <typename S>
std::string Bytes(std::initializer_list<S> values) {
  std::string s;
  for (S v : values) s.append(reinterpret_cast<const char*>(&v), sizeof(S));
  return s;
}

TEST(Safetensors, ParsesEveryDtype) {
  const std::string data = Bytes<double>({1.5, -2.0}) + Bytes<float>({0.25f, 3.0f, -1.0f}) +
                           Bytes<int64_t>({7, -9}) + Bytes<uint16_t>({0x3C00, 0xC000, 0x0001}) +  // F16 1, -2, 2^-24
                           Bytes<uint16_t>({0x3F80, 0x4040}) +                                    // BF16 1, 3
                           Bytes<int32_t>({5}) + Bytes<uint8_t>({1, 0});
  const std::string header =
      R"({"a":{"dtype":"F64","shape":[2],"data_offsets":[0,16]},)"
      R"("b":{"dtype":"F32","shape":[3,1],"data_offsets":[16,28]},)"
      R"("c":{"dtype":"I64","shape":[2],"data_offsets":[28,44]},)"
      R"("d":{"dtype":"F16","shape":[3],"data_offsets":[44,50]},)"
      R"("e":{"dtype":"BF16","shape":[2],"data_offsets":[50,54]},)"
      R"("f":{"dtype":"I32","shape":[],"data_offsets":[54,58]},)"
      R"("g":{"dtype":"BOOL","shape":[2],"data_offsets":[58,60]},)"
      R"("__metadata__":{"format":"pt","k":"v"}})";
  const SafetensorsFile file = SafetensorsFile::Parse(HandMade(header, data), "mem");
  EXPECT_EQ(file.Names().size(), 7u);
  EXPECT_EQ(file.Get("a").values, (std::vector<double>{1.5, -2.0}));
  EXPECT_EQ(file.Get("b").values, (std::vector<double>{0.25, 3.0, -1.0}));
  EXPECT_EQ(file.Get("b").ShapeString(), "(3, 1)");
  EXPECT_EQ(file.Get("c").values, (std::vector<double>{7, -9}));
  EXPECT_EQ(file.Get("d").values, (std::vector<double>{1.0, -2.0, std::ldexp(1.0, -24)}));
  EXPECT_EQ(file.Get("e").values, (std::vector<double>{1.0, 3.0}));
  EXPECT_EQ(file.Get("f").values, (std::vector<double>{5}));
  EXPECT_EQ(file.Get("f").size(), 1);
  EXPECT_EQ(file.Get("g").values, (std::vector<double>{1, 0}));
  EXPECT_EQ(file.Metadata("k"), "v");
  EXPECT_EQ(file.Matrix("b", 3, 1)(2, 0), -1.0);
}

TEST(Safetensors, WriterRoundTripsAtomically) {
  TempFile tmp("roundtrip.safetensors");
  Tensor t;
  t.dtype = "F64";
  t.shape = {2, 3};
  t.values = {1, 2, 3, 4, 5, 6.125};
  WriteSafetensors(tmp.path(), {{"w", t}}, {{"m", "x"}});
  SafetensorsFile f64 = SafetensorsFile::Read(tmp.path());
  EXPECT_EQ(f64.Get("w").values, t.values);
  EXPECT_EQ(f64.Get("w").dtype, "F64");
  EXPECT_EQ(f64.Metadata("m"), "x");
  WriteSafetensors(tmp.path(), {{"w", t}}, {}, "F32");  // replaces the file
  SafetensorsFile f32 = SafetensorsFile::Read(tmp.path());
  EXPECT_EQ(f32.Get("w").dtype, "F32");
  EXPECT_EQ(f32.Get("w").values, t.values);  // all exactly representable in float
  EXPECT_TRUE(f32.metadata().empty());
}

TEST(Safetensors, ErrorsNameTheProblem) {
  auto message = [](const std::string& bytes) {
    try {
      SafetensorsFile::Parse(bytes, "bad.safetensors");
    } catch (const std::invalid_argument& err) {
      return std::string(err.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("abc").find("too short"), std::string::npos);
  std::string huge(8, '\0');
  huge[0] = 100;
  EXPECT_NE(message(huge + "{}").find("exceeds the file"), std::string::npos);
  EXPECT_NE(message(HandMade("{nope", "")).find("not JSON"), std::string::npos);
  const std::string short_data = HandMade(R"({"t":{"dtype":"F32","shape":[4],"data_offsets":[0,8]}})",
                                          std::string(8, '\0'));
  EXPECT_NE(message(short_data).find("do not fit shape (4,)"), std::string::npos);
  EXPECT_NE(message(HandMade(R"({"t":{"dtype":"C64","shape":[1],"data_offsets":[0,8]}})", std::string(8, '\0')))
                .find("unsupported dtype C64"),
            std::string::npos);

  const SafetensorsFile file = SafetensorsFile::Parse(
      HandMade(R"({"w":{"dtype":"F64","shape":[2],"data_offsets":[0,16]}})", Bytes<double>({1, 2})), "x.st");
  try {
    file.Get("missing");
    FAIL();
  } catch (const std::invalid_argument& err) {
    EXPECT_NE(std::string(err.what()).find("x.st: no tensor 'missing' (the file has 1: w)"), std::string::npos);
  }
  try {
    file.Matrix("w", 1, 2);
    FAIL();
  } catch (const std::invalid_argument& err) {
    EXPECT_NE(std::string(err.what()).find("'w' must have shape (1, 2), got (2,)"), std::string::npos);
  }
  EXPECT_THROW(SafetensorsFile::Read("/nonexistent/m3c.safetensors"), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::nn
