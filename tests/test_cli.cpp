// The cullpipe tool end to end: runs the built binary and checks its output and exit codes.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>

namespace {

namespace fs = std::filesystem;

struct Result {
  int code = -1;
  std::string out, err;
};

fs::path temp_dir() {
  static const fs::path dir = [] {
    fs::path d = fs::temp_directory_path() / ("cullpipe_cli_test_" + std::to_string(::getpid()));
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Runs `cullpipe ARGS` through the shell with optional environment prefix.
Result cullpipe(const std::string& args, const std::string& env = "") {
  const fs::path out = temp_dir() / "stdout.txt", err = temp_dir() / "stderr.txt";
  const std::string cmd = env + " '" CULLPIPE_EXE "' " + args + " >'" + out.string() + "' 2>'" + err.string() + "'";
  const int status = std::system(cmd.c_str());
  Result r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

const std::string kData = CULLPIPE_TEST_DATA;
const std::string kNoVulkan = "VK_ICD_FILENAMES=/nonexistent/icd.json VK_DRIVER_FILES=/nonexistent/icd.json";

TEST(Cli, HelpListsSubcommands) {
  const Result r = cullpipe("--help");
  EXPECT_EQ(r.code, 0);
  for (const char* word : {"run", "classify", "generate", "devices", "render", "bounds", "bvh"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word;
}

TEST(Cli, RunWithNoArgumentsCullsTheDefaultSceneAndAgrees) {
  const Result r = cullpipe("--validate_placeholder_is_not_an_option");
  EXPECT_EQ(r.code, 2) << "unknown options are rejected";
  const Result ok = cullpipe("");
  EXPECT_EQ(ok.code, 0) << ok.err;
  EXPECT_NE(ok.out.find("default.json"), std::string::npos) << ok.out;
  EXPECT_NE(ok.out.find("identical (gpu == cpu)"), std::string::npos) << ok.out;
}

TEST(Cli, RunEveryVolumeKindWithValidation) {
  for (const char* bv : {"aabb", "obb", "sphere"}) {
    const fs::path json = temp_dir() / "summary.json";
    const Result r = cullpipe(std::string("run --generate clustered:3000 --seed 4 --views 3 --validate --bv ") + bv +
                              " --json '" + json.string() + "'");
    ASSERT_EQ(r.code, 0) << r.out << r.err;
    EXPECT_EQ(r.err, "") << "validation or other messages";
    const auto j = nlohmann::json::parse(slurp(json));
    EXPECT_EQ(j["objects"], 3000);
    EXPECT_EQ(j["bv"], bv);
    EXPECT_EQ(j["agree"], true);
    EXPECT_EQ(j["per_view"].size(), 3u);
    EXPECT_GT(j["gpu_wall_ns"].get<double>(), 0.0);
    EXPECT_TRUE(j.contains("gpu_ns"));  // 0 on a queue without timestamps
    EXPECT_GT(j["gpu_upload_ns"].get<double>(), 0.0);
    EXPECT_FALSE(j.contains("cpu_upload_ns")) << "the reference has no upload";
  }
}

TEST(Cli, ClassifyGivesTheDerivedAnswers) {
  const Result r = cullpipe("classify '" + kData + "/classify_cube.json' --validate");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  const std::vector<std::string> expected = {"inside",       "outside", "intersecting", "inside", "outside",
                                             "intersecting", "inside",  "intersecting", "outside"};
  EXPECT_EQ(j["cpu"].get<std::vector<std::string>>(), expected);
  EXPECT_EQ(j["gpu"].get<std::vector<std::string>>(), expected);
}

TEST(Cli, ClassifyReadsStandardInputAndOneBackend) {
  const Result r = cullpipe("classify - --backend cpu < '" + kData + "/classify_cube.json'");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j.contains("cpu"));
  EXPECT_FALSE(j.contains("gpu"));
}

TEST(Cli, DumpReadsBackIntoClassifyWithTheSameAnswers) {
  const fs::path dump = temp_dir() / "dump.json";
  const Result r = cullpipe("run --generate uniform:2000 --bv obb --dump '" + dump.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto d = nlohmann::json::parse(slurp(dump));
  ASSERT_EQ(d["volumes"].size(), 2000u);
  std::vector<std::string> dumped;
  for (const auto& v : d["volumes"]) dumped.push_back(v["class"]);
  const Result c = cullpipe("classify '" + dump.string() + "'");
  ASSERT_EQ(c.code, 0) << c.err;
  const auto j = nlohmann::json::parse(c.out);
  EXPECT_EQ(j["cpu"].get<std::vector<std::string>>(), dumped);
  EXPECT_EQ(j["gpu"].get<std::vector<std::string>>(), dumped);
}

TEST(Cli, MultiViewDumpRoundTrips) {
  const fs::path dump = temp_dir() / "dump_views.json";
  ASSERT_EQ(cullpipe("run --generate city:500 --views 3 --bv sphere --dump '" + dump.string() + "'").code, 0);
  const auto d = nlohmann::json::parse(slurp(dump));
  ASSERT_EQ(d["frusta"].size(), 3u);
  const Result c = cullpipe("classify '" + dump.string() + "'");
  ASSERT_EQ(c.code, 0) << c.err;
  const auto j = nlohmann::json::parse(c.out);
  ASSERT_EQ(j["views"].size(), 3u);
  for (std::size_t v = 0; v < 3; ++v)
    for (std::size_t i = 0; i < 500; ++i) ASSERT_EQ(j["views"][v]["gpu"][i], d["volumes"][i]["classes"][v]);
}

// Hierarchical culling from the tool: every view agrees with the CPU traversal, the classes
// equal flat culling's (the dump reads back into `classify`), and test counts are recorded.
TEST(Cli, RunWithTheBvhAgreesAndDumpsTestCounts) {
  const fs::path json = temp_dir() / "bvh_summary.json", dump = temp_dir() / "bvh_dump.json";
  const Result r =
      cullpipe("run --generate city:4000 --views 3 --validate --cull bvh --builder median --leaf-size 2 --json '" +
               json.string() + "' --dump '" + dump.string() + "'");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_NE(r.out.find("bvh: median"), std::string::npos) << r.out;
  const auto j = nlohmann::json::parse(slurp(json));
  EXPECT_EQ(j["cull"], "bvh");
  EXPECT_EQ(j["builder"], "median");
  EXPECT_EQ(j["agree"], true);
  EXPECT_GT(j["bvh"]["nodes"].get<int>(), 1000);
  for (const auto& v : j["per_view"]) {
    EXPECT_GT(v["node_tests"].get<int>(), 0);
    EXPECT_LT(v["object_tests"].get<int>(), 4000);
  }
  const auto d = nlohmann::json::parse(slurp(dump));
  ASSERT_EQ(d["tests"].size(), 3u);
  EXPECT_EQ(d["tests"][0]["cull"], "bvh");
  EXPECT_EQ(d["tests"][0]["node_tests"], j["per_view"][0]["node_tests"]);
  const Result c = cullpipe("classify '" + dump.string() + "' --backend cpu");  // flat reference
  ASSERT_EQ(c.code, 0) << c.err;
  const auto flat = nlohmann::json::parse(c.out);
  for (std::size_t v = 0; v < 3; ++v)
    for (std::size_t i = 0; i < 4000; i += 7) ASSERT_EQ(flat["views"][v]["cpu"][i], d["volumes"][i]["classes"][v]) << i;
  EXPECT_EQ(d["tests"][0]["range_objects"], 0);  // the reference descends to the leaves by default
  // Ranges of up to 64 objects on either CPU path: fewer node tests, more object tests, the
  // same classes; the GPU (to the leaves) still agrees, its counts proved against the scalar
  // traversal's with no ranges.
  for (const char* cpu : {"reference", "fast"}) {
    const Result g =
        cullpipe("run --generate city:4000 --views 3 --validate --cull bvh --builder median --leaf-size 2 --cpu " +
                 std::string(cpu) + " --range-objects 64 --json '" + json.string() + "'");
    ASSERT_EQ(g.code, 0) << g.out << g.err;
    EXPECT_NE(g.out.find("ranges of <= 64 objects"), std::string::npos) << g.out;
    const auto gj = nlohmann::json::parse(slurp(json));
    EXPECT_EQ(gj["agree"], true) << cpu;
    EXPECT_EQ(gj["range_objects"], 64) << cpu;
    for (std::size_t v = 0; v < 3; ++v) {
      EXPECT_LT(gj["per_view"][v]["node_tests"], j["per_view"][v]["node_tests"]) << cpu << " view " << v;
      EXPECT_GT(gj["per_view"][v]["object_tests"], j["per_view"][v]["object_tests"]) << cpu << " view " << v;
      EXPECT_EQ(gj["per_view"][v]["visible"], j["per_view"][v]["visible"]) << cpu << " view " << v;
      EXPECT_EQ(gj["per_view"][v]["inside"], j["per_view"][v]["inside"]) << cpu << " view " << v;
    }
  }
  // Unasked, the fast path's ranges depend on the volumes: 160 objects for AABBs and spheres,
  // 96 for OBBs (CpuBvhCullOptions::default_range_objects).
  for (const auto& [bv, range] : {std::pair{"aabb", 160}, std::pair{"sphere", 160}, std::pair{"obb", 96}}) {
    const Result g = cullpipe("run --generate city:2000 --cull bvh --backend cpu --cpu fast --bv " + std::string(bv) +
                              " --json '" + json.string() + "' --dump '" + dump.string() + "'");
    ASSERT_EQ(g.code, 0) << g.out << g.err;
    EXPECT_NE(g.out.find("ranges of <= " + std::to_string(range) + " objects"), std::string::npos) << bv << "\n"
                                                                                                   << g.out;
    EXPECT_EQ(nlohmann::json::parse(slurp(json))["range_objects"], range) << bv;
    EXPECT_EQ(nlohmann::json::parse(slurp(dump))["tests"][0]["range_objects"], range) << bv;
  }
  // Flat culling records one object test per object and no node tests.
  const Result f = cullpipe("run --generate city:500 --dump '" + dump.string() + "'");
  ASSERT_EQ(f.code, 0) << f.err;
  const auto fd = nlohmann::json::parse(slurp(dump));
  EXPECT_EQ(fd["tests"][0]["cull"], "flat");
  EXPECT_EQ(fd["tests"][0]["node_tests"], 0);
  EXPECT_EQ(fd["tests"][0]["object_tests"], 500);
}

// Every volume kind, flat and hierarchical, with the reference or the fast CPU path on the
// CPU side: the GPU agrees object by object and the report names the CPU path.
TEST(Cli, EveryKindFlatAndHierarchicalOnEitherCpuPath) {
  const fs::path json = temp_dir() / "kinds.json";
  for (const char* bv : {"aabb", "obb", "sphere"})
    for (const char* cull : {"flat", "bvh"})
      for (const char* cpu : {"reference", "fast"}) {
        const std::string args = std::string("run --generate clustered:3000 --views 2 --validate --bv ") + bv +
                                 " --cull " + cull + " --cpu " + cpu;
        const Result r = cullpipe(args + " --json '" + json.string() + "'");
        ASSERT_EQ(r.code, 0) << args << "\n" << r.out << r.err;
        const auto j = nlohmann::json::parse(slurp(json));
        EXPECT_EQ(j["agree"], true) << args;
        EXPECT_EQ(j["bv"], bv);
        const std::string path = j["cpu_path"];
        EXPECT_EQ(path.find(std::string(cpu) == "fast" ? "fast" : "reference") != std::string::npos, true)
            << args << ": " << path;
        EXPECT_NE(r.out.find("cpu " + path), std::string::npos) << r.out;
        // The fast path is itself checked against the reference.
        if (std::string(cpu) == "fast") {
          EXPECT_NE(r.out.find("gpu == fast cpu == reference"), std::string::npos) << r.out;
        }
        if (std::string(cull) == "bvh") {
          EXPECT_GT(j["per_view"][0]["node_tests"].get<int>(), 0) << args;
          EXPECT_LT(j["per_view"][0]["object_tests"].get<int>(), 3000) << args;
        }
      }
  // Without Vulkan the fast CPU path runs alone.
  const Result r = cullpipe("run --generate uniform:5000 --bv sphere --cull bvh --cpu fast --backend cpu", kNoVulkan);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("cpu fast hierarchical"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("; upload "), std::string::npos) << r.out;  // the fast culler's copy of the scene
  const fs::path upload_json = temp_dir() / "fast_upload.json";
  const Result flat =
      cullpipe("run --generate uniform:5000 --cpu fast --backend cpu --json '" + upload_json.string() + "'", kNoVulkan);
  ASSERT_EQ(flat.code, 0) << flat.err;
  const auto uploads = nlohmann::json::parse(slurp(upload_json));
  EXPECT_GT(uploads["cpu_upload_ns"].get<double>(), 0.0);
  EXPECT_FALSE(uploads.contains("gpu_upload_ns"));
  EXPECT_NE(r.out.find("(fast cpu == reference)"), std::string::npos) << r.out;
}

TEST(Cli, BvhCommandReportsEveryBuilder) {
  const Result list = cullpipe("bvh --list");
  ASSERT_EQ(list.code, 0) << list.err;
  for (const char* name : {"binned-sah", "median", "agglomerative-local", "insertion-bnb", "top-down:"})
    EXPECT_NE(list.out.find(name), std::string::npos) << name;
  const fs::path json = temp_dir() / "bvh_builders.json";
  const Result r = cullpipe("bvh --generate clustered:1500 --builder all --json '" + json.string() + "'");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  const auto j = nlohmann::json::parse(slurp(json));
  EXPECT_EQ(j["objects"], 1500);
  std::set<std::string> names;
  for (const auto& b : j["builders"]) {
    names.insert(b["builder"].get<std::string>());
    EXPECT_GT(b["sah_cost"].get<double>(), 1.0) << b["builder"];
    EXPECT_LE(b["max_leaf_size"].get<int>(), 4) << b["builder"];
    EXPECT_GE(b["build_ns"].get<double>(), 0.0);
  }
  EXPECT_GE(names.size(), 15u);
  EXPECT_TRUE(names.count("agglomerative-brute"));  // 1500 objects: within its limit
  const Result one = cullpipe(
      "bvh --generate uniform:3000 --builder top-down:axis=pca,split=median,cost=sah insertion-greedy+rotations");
  ASSERT_EQ(one.code, 0) << one.err;
  EXPECT_NE(one.out.find("insertion-greedy+rotations"), std::string::npos) << one.out;
  // Leaves where the SAH says, capped at 16: with objects at a quarter of a node test, larger
  // leaves than the default's at most 4.
  const fs::path sah = temp_dir() / "bvh_sah_leaves.json";
  const Result leaves = cullpipe("bvh --generate uniform:5000 --sah-leaves --object-cost 0.25 --leaf-size 16 --json '" +
                                 sah.string() + "'");
  ASSERT_EQ(leaves.code, 0) << leaves.err;
  const auto js = nlohmann::json::parse(slurp(sah));
  EXPECT_EQ(js["sah_leaves"], true);
  EXPECT_GT(js["builders"][0]["max_leaf_size"].get<int>(), 4);
  EXPECT_LE(js["builders"][0]["max_leaf_size"].get<int>(), 16);
  EXPECT_EQ(cullpipe("bvh --generate uniform:100 --sah-leaves --object-cost 0").code, 2);
}

TEST(Cli, BadBvhOptionsAreClearErrors) {
  Result r = cullpipe("bvh --generate uniform:100 --builder no-such-builder");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("no-such-builder"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("binned-sah"), std::string::npos) << "lists the known builders: " << r.err;
  r = cullpipe("run --generate uniform:100 --cpu quick");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--cpu"), std::string::npos) << r.err;
  r = cullpipe("run --generate uniform:100 --cpu fast --backend gpu");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--cpu fast needs the CPU side"), std::string::npos) << r.err;
  r = cullpipe("run --generate uniform:100 --cull bvh --builder top-down:axis=sideways");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("sideways"), std::string::npos) << r.err;
  r = cullpipe("run --generate uniform:100 --cull octree");
  EXPECT_EQ(r.code, 2);
  // The exact O(n^2) agglomerative builder is an oracle: refused on large scenes, up front.
  r = cullpipe("run --generate uniform:30000 --cull bvh --builder agglomerative-pq");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("oracle"), std::string::npos) << r.err;
  r = cullpipe("bvh --generate uniform:30000 --builder binned-sah agglomerative-brute");
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.out.find("binned-sah  "), std::string::npos) << "nothing built before the error: " << r.out;
  // No Vulkan: the CPU hierarchical traversal still runs.
  r = cullpipe("run --generate uniform:1000 --cull bvh --backend cpu", kNoVulkan);
  EXPECT_EQ(r.code, 0) << r.err;
}

TEST(Cli, BadInputIsAClearErrorNotACrash) {
  const fs::path bad = temp_dir() / "bad.json";
  auto write = [&](const std::string& text) { std::ofstream(bad) << text; };
  struct Case {
    std::string text, message;
  };
  const std::vector<Case> cases = {
      {"{not json", "invalid JSON"},
      {R"({"frustum": {"planes": [[1,0,0,1]]}, "volumes": [{"sphere": {"center": [0,0,0], "radius": -2}}]})",
       "volumes[0].sphere: radius is negative"},
      {R"({"frustum": {"planes": [[1,0,0,1]]}, "volumes": [{"aabb": {"min": [0,0,1e39], "max": [1,1,1]}}]})",
       "volumes[0].aabb.min[2]: number out of float range"},
      {R"({"frustum": {"planes": [[1,0,0,1]]}, "volumes": [{"aabb": {"min": [0,0,1e999], "max": [1,1,1]}}]})",
       "number overflow"},
      {R"({"frustum": {"view_proj": [1,0,0,0, 1,0,0,0, 0,0,1,0, 0,0,0,1]}, "volumes": []})", "singular"},
      {R"({"volumes": []})", "missing \"frustum\""},
      {R"({"frustum": {"planes": [[1,0,0,1]]}, "frusta": [], "volumes": []})", "not both"},
  };
  for (const Case& c : cases) {
    write(c.text);
    const Result r = cullpipe("classify '" + bad.string() + "'");
    EXPECT_EQ(r.code, 2) << c.text;
    EXPECT_NE(r.err.find(bad.string()), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << r.err;
  }
  EXPECT_EQ(cullpipe("classify /nonexistent/x.json").code, 2);
  EXPECT_EQ(cullpipe("run --bv cone").code, 2);
  EXPECT_EQ(cullpipe("run --generate town:5").code, 2);
  EXPECT_EQ(cullpipe("run --scene /nonexistent/scene.json").code, 2);
  EXPECT_EQ(cullpipe("run --views 0").code, 2);
}

TEST(Cli, NoVulkanDeviceIsClearAndTheCpuBackendStillWorks) {
  const Result gpu = cullpipe("run --generate city:100 --backend gpu", kNoVulkan);
  EXPECT_EQ(gpu.code, 3);
  EXPECT_NE(gpu.err.find("no Vulkan device"), std::string::npos) << gpu.err;
  EXPECT_NE(gpu.err.find("--backend cpu"), std::string::npos) << gpu.err;
  const Result cpu = cullpipe("run --generate city:100 --backend cpu", kNoVulkan);
  EXPECT_EQ(cpu.code, 0) << cpu.err;
  EXPECT_NE(cpu.out.find("cpu reference"), std::string::npos);
  const Result classify = cullpipe("classify '" + kData + "/classify_cube.json' --backend cpu", kNoVulkan);
  EXPECT_EQ(classify.code, 0) << classify.err;
}

TEST(Cli, OutOfDeviceMemoryIsClearWritesNothingAndTheCpuBackendStillWorks) {
  // A 16 MiB device-memory budget cannot hold a million AABBs (32 MB of bounds).
  const fs::path json = temp_dir() / "oom.json";
  fs::remove(json);
  const Result gpu =
      cullpipe("run --generate uniform:1000000 --backend gpu --gpu-memory 16 --json '" + json.string() + "'");
  EXPECT_EQ(gpu.code, 3);
  EXPECT_NE(gpu.err.find("VK_ERROR_OUT_OF_DEVICE_MEMORY"), std::string::npos) << gpu.err;
  EXPECT_NE(gpu.err.find("memory budget of 16777216 bytes"), std::string::npos) << gpu.err;
  EXPECT_NE(gpu.err.find("--backend cpu"), std::string::npos) << gpu.err;
  EXPECT_FALSE(fs::exists(json)) << "no output file after a failed run";
  EXPECT_FALSE(fs::exists(json.string() + ".tmp"));
  const Result cpu =
      cullpipe("run --generate uniform:1000000 --backend cpu --gpu-memory 16 --json '" + json.string() + "'");
  EXPECT_EQ(cpu.code, 0) << cpu.err;
  EXPECT_TRUE(fs::exists(json));
  // Enough budget: the same scene on the GPU agrees with the CPU.
  const Result fits = cullpipe("run --generate uniform:100000 --gpu-memory 64");
  EXPECT_EQ(fits.code, 0) << fits.err;
}

TEST(Cli, GenerateWritesALoadableScene) {
  const fs::path scene = temp_dir() / "gen.json";
  ASSERT_EQ(cullpipe("generate city:300 --seed 2 --out '" + scene.string() + "'").code, 0);
  const Result r = cullpipe("run --scene '" + scene.string() + "' --backend both");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("300 objects"), std::string::npos) << r.out;
}

TEST(Cli, StreetsSceneFileKeepsItsPath) {
  const fs::path scene = temp_dir() / "streets.json";
  ASSERT_EQ(cullpipe("generate streets:500 --seed 3 --out '" + scene.string() + "'").code, 0);
  const auto j = nlohmann::json::parse(slurp(scene));
  ASSERT_TRUE(j.contains("path"));
  EXPECT_EQ(j["path"][0], j["camera"]);
  const Result r = cullpipe("run --scene '" + scene.string() + "' --views 5 --backend cpu");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("500 objects"), std::string::npos) << r.out;
}

TEST(Cli, BoundsReportsEveryBuilder) {
  const fs::path pts = temp_dir() / "pts.txt", json = temp_dir() / "bounds.json";
  std::ofstream(pts)
      << "# cube corners and the centre\n-1 -1 -1\n1 -1 -1\n-1 1 -1\n1 1 -1\n-1 -1 1\n1 -1 1\n-1 1 1\n1 1 1\n0 0 0\n";
  const Result r = cullpipe("bounds --points '" + pts.string() + "' --json '" + json.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("9 points"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("8 vertices"), std::string::npos) << r.out;
  const auto j = nlohmann::json::parse(slurp(json))["sets"][0];
  ASSERT_EQ(j["volumes"].size(), 8u);
  for (const auto& v : j["volumes"]) {
    EXPECT_TRUE(v.contains("builder") && v.contains("time_ms"));
    if (v.contains("sphere")) {  // exact: the cube's circumradius; the others enclose it
      if (v["builder"] == "sphere-exact") {
        EXPECT_NEAR(v["sphere"]["radius"].get<double>(), std::sqrt(3.0), 1e-5);
      }
      EXPECT_GE(v["sphere"]["radius"].get<double>(), std::sqrt(3.0) - 1e-6) << v["builder"];
    }
  }
  std::ofstream(pts) << "1 2 3\n4 5\n";
  const Result bad = cullpipe("bounds --points '" + pts.string() + "'");
  EXPECT_EQ(bad.code, 2);
  EXPECT_NE(bad.err.find("pts.txt:2: expected three coordinates"), std::string::npos) << bad.err;
}

TEST(Cli, GltfSceneRunsAgreesAndDumpsWhereEachObjectCameFrom) {
  const fs::path scene = fs::path(CULLPIPE_SHARED_DIR) / "scenes" / "CesiumMilkTruck" / "CesiumMilkTruck.gltf";
  if (!fs::exists(scene)) GTEST_SKIP() << scene << " not present";
  const fs::path dump = temp_dir() / "truck.json";
  for (const char* bv : {"aabb", "obb", "sphere"}) {
    const Result r = cullpipe("run --validate --views 4 --bv " + std::string(bv) + " --scene '" + scene.string() +
                              "' --dump '" + dump.string() + "'");
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("5 objects"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("identical (gpu == cpu)"), std::string::npos) << r.out;
    const auto d = nlohmann::json::parse(slurp(dump));
    ASSERT_EQ(d["volumes"].size(), 5u);
    std::set<std::pair<int, int>> mesh_prims;
    for (const auto& v : d["volumes"]) {
      const auto& o = v["object"];
      ASSERT_TRUE(o.contains("gltf") && o.contains("aabb") && o.contains("obb") && o.contains("sphere")) << v.dump();
      EXPECT_GE(o["gltf"]["node"].get<int>(), 0);
      EXPECT_EQ(v.contains(bv), true);
      EXPECT_EQ(v[bv], o[bv]);  // the culled volume is the object's volume of that kind
      mesh_prims.insert({o["gltf"]["mesh"].get<int>(), o["gltf"]["primitive"].get<int>()});
    }
    EXPECT_EQ(mesh_prims.size(), 4u);  // 2 meshes, 4 primitives; the wheels are used twice
    // The dump reads back into classify with the same answers.
    const Result c = cullpipe("classify '" + dump.string() + "'");
    ASSERT_EQ(c.code, 0) << c.err;
  }
  // Every builder and update method can be chosen; repeated into a larger scene.
  const Result big =
      cullpipe("run --scene '" + scene.string() +
               "' --obb exact --sphere refined --aabb-update hill-climb --instances 300 --layout random");
  ASSERT_EQ(big.code, 0) << big.err;
  EXPECT_NE(big.out.find("1500 objects"), std::string::npos) << big.out;
  EXPECT_NE(big.out.find("identical (gpu == cpu)"), std::string::npos) << big.out;
  // Options that only make sense for glTF, and bad names, are input errors.
  EXPECT_EQ(cullpipe("run --generate city:10 --camera 0").code, 2);
  const Result bad_cam = cullpipe("run --scene '" + scene.string() + "' --camera front");
  EXPECT_EQ(bad_cam.code, 2);
  EXPECT_NE(bad_cam.err.find("no camera \"front\""), std::string::npos) << bad_cam.err;
  EXPECT_EQ(cullpipe("run --scene '" + scene.string() + "' --obb best").code, 2);
  EXPECT_EQ(cullpipe("run --scene '" + scene.string() + "' --layout spiral").code, 2);
  const fs::path broken = temp_dir() / "broken.gltf";
  std::ofstream(broken) << R"({"asset":{"version":"2.0"},"nodes":[{"children":[0]}],"scenes":[{"nodes":[0]}]})";
  const Result cyc = cullpipe("run --scene '" + broken.string() + "'");
  EXPECT_EQ(cyc.code, 2);
  EXPECT_NE(cyc.err.find("broken.gltf: nodes[0] is its own child"), std::string::npos) << cyc.err;
}

TEST(Cli, RenderWritesImagesAndChecksCulledEqualsUnculled) {
  const fs::path png = temp_dir() / "city.png", top = temp_dir() / "city_top.png";
  const Result r = cullpipe("render --generate city:800 --width 200 --height 120 --check --validate --out '" +
                            png.string() + "' --top-down '" + top.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("is identical, pixel for pixel"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("of 800 objects drawn"), std::string::npos) << r.out;
  for (const fs::path& p : {png, top}) {
    ASSERT_TRUE(fs::exists(p)) << p;
    EXPECT_EQ(slurp(p).substr(1, 3), "PNG");
  }
  const Result all =
      cullpipe("render --generate city:50 --no-cull --width 64 --height 64 --out '" + png.string() + "'");
  ASSERT_EQ(all.code, 0) << all.err;
  EXPECT_NE(all.out.find("no culling: 50 draws"), std::string::npos) << all.out;
  EXPECT_EQ(cullpipe("render --generate city:50").code, 2);  // --out is required
  const Result bad = cullpipe("render --generate city:50 --out /nonexistent-dir/x.png");
  EXPECT_EQ(bad.code, 2) << bad.err;
  EXPECT_NE(bad.err.find("/nonexistent-dir/x.png: cannot write"), std::string::npos) << bad.err;
}

TEST(Cli, RenderWithOcclusionPrintsEachFrameAndKeepsTheImage) {
  const fs::path png = temp_dir() / "occluded.png";
  const Result r = cullpipe("render --occlusion --frames 3 --check --validate --width 240 --height 135 --out '" +
                            png.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* frame : {"frame 0:", "frame 1:", "frame 2:"})
    EXPECT_NE(r.out.find(frame), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("260 kept by the frustum, 0 occluded, 0 drawn first"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("DIFFERS"), std::string::npos) << r.out;
  // From the second frame on, the default camera's hidden buildings are culled.
  const std::size_t second = r.out.find("frame 1:");
  ASSERT_NE(second, std::string::npos);
  EXPECT_EQ(r.out.find(" 0 occluded", second), std::string::npos) << r.out;
  EXPECT_EQ(cullpipe("render --occlusion --no-cull --out '" + png.string() + "'").code, 2);
  EXPECT_EQ(cullpipe("render --occlusion --texels 3 --out '" + png.string() + "'").code, 2);
}

// render --clusters on a shipped scene: every frame's image checked against the unculled one,
// the clusters and triangles reported; back-facing clusters culled on the duck of the shared
// scenes when present.
TEST(Cli, RenderWithClustersChecksTheImage) {
  const fs::path png = temp_dir() / "clusters.png", top = temp_dir() / "clusters_top.png";
  fs::remove(top);
  const Result r =
      cullpipe("render --clusters --occlusion --frames 2 --check --validate --width 240 --height 135 --out '" +
               png.string() + "' --top-down '" + top.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(top));
  EXPECT_NE(r.out.find("top-down clusters"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("clusters: "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(" of culled objects, "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("triangles: "), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("DIFFERS"), std::string::npos) << r.out;
  const fs::path duck = fs::path(CULLPIPE_TEST_DATA) / "../../../shared/scenes/Duck/Duck.gltf";
  if (fs::exists(duck)) {
    const Result d = cullpipe("render --clusters --check --validate --width 240 --height 135 --scene '" +
                              duck.string() + "' --out '" + png.string() + "'");
    ASSERT_EQ(d.code, 0) << d.err;
    EXPECT_EQ(d.out.find(" 0 back-facing"), std::string::npos) << d.out;
    EXPECT_EQ(d.out.find("DIFFERS"), std::string::npos) << d.out;
  }
  EXPECT_EQ(cullpipe("render --clusters --no-cull --out '" + png.string() + "'").code, 2);
  EXPECT_EQ(cullpipe("render --clusters --cone-weight 2 --out '" + png.string() + "'").code, 2);
}

// run --clusters (two occlusion phases, as with --occlusion) checks every (object, cluster) pair
// against the reference on each frame, and reports the triangles submitted, those of the kept
// objects drawn whole and those owning a pixel.
TEST(Cli, RunWithClustersChecksEveryPairAgainstTheReference) {
  const fs::path json = temp_dir() / "clusters.json";
  const Result r = cullpipe(
      "run --clusters --generate meshes:300 --views 40 --frames 3 --validate "
      "--width 240 --height 135 --json '" +
      json.string() + "'");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("cluster-frame classes equal the reference's"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(" back-facing, "), std::string::npos) << r.out;
  const nlohmann::json j = nlohmann::json::parse(slurp(json));
  EXPECT_EQ(j["cluster_mismatches"], 0);
  ASSERT_EQ(j["per_frame"].size(), 3u);
  EXPECT_GT(j["per_frame"][1]["clusters_back_facing"].get<std::size_t>(), 0u);
  EXPECT_GT(j["per_frame"][1]["clusters_drawn"].get<std::size_t>(), 0u);
  const nlohmann::json& f1 = j["per_frame"][1];
  EXPECT_LT(f1["triangles"].get<std::uint64_t>(), f1["object_triangles"].get<std::uint64_t>());
  if (!f1["visible_triangles"].is_null()) {  // every triangle owning a pixel is submitted
    EXPECT_GT(f1["visible_triangles"].get<std::uint64_t>(), 0u);
    EXPECT_LE(f1["visible_triangles"].get<std::uint64_t>(), f1["triangles"].get<std::uint64_t>());
  }
  EXPECT_NE(r.out.find(" by the kept objects whole ("), std::string::npos) << r.out;
}

// run --occlusion walks the streets' path with both passes checked against the reference on
// every frame's pyramid; the JSON and the dump carry each frame, OCCLUDED included.
TEST(Cli, RunWithOcclusionChecksEveryFrameAgainstTheReference) {
  const fs::path json = temp_dir() / "occlusion.json", dump = temp_dir() / "occlusion_dump.json";
  const Result r = cullpipe(
      "run --occlusion --generate streets:3000 --views 20 --frames 4 --cull bvh --validate "
      "--width 240 --height 135 --json '" +
      json.string() + "' --dump '" + dump.string() + "'");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("flat pass == hierarchical pass == reference"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("every object owning a pixel was drawn"), std::string::npos) << r.out;
  const nlohmann::json j = nlohmann::json::parse(slurp(json));
  EXPECT_EQ(j["agree"], true);
  EXPECT_EQ(j["missed"], 0);
  ASSERT_EQ(j["per_frame"].size(), 4u);
  EXPECT_EQ(j["per_frame"][0]["occluded"], 0);  // the first frame knows no visible objects
  // (A frame after a jump of the camera starts from a sparse first phase and keeps more, so the
  // culling is judged over the frames together.)
  std::size_t occluded = 0, drawn = 0;
  for (std::size_t f = 1; f < 4; ++f) {
    const auto& frame = j["per_frame"][f];
    occluded += frame["occluded"].get<std::size_t>();
    drawn += frame["drawn"].get<std::size_t>();
    EXPECT_GE(frame["drawn"].get<std::size_t>(), frame["owning"].get<std::size_t>()) << f;
    EXPECT_EQ(frame["frustum"].get<std::size_t>(),
              frame["drawn"].get<std::size_t>() + frame["occluded"].get<std::size_t>());
  }
  EXPECT_GT(occluded, 2 * drawn);
  const nlohmann::json d = nlohmann::json::parse(slurp(dump));
  EXPECT_NE(d.dump().find("\"occluded\""), std::string::npos);
  // What it cannot do is refused by name.
  const Result cpu = cullpipe("run --occlusion --backend cpu");
  EXPECT_EQ(cpu.code, 2);
  EXPECT_NE(cpu.err.find("--backend gpu or both"), std::string::npos) << cpu.err;
  EXPECT_EQ(cullpipe("run --occlusion --texels 5").code, 2);
}

TEST(Cli, DevicesListsAtLeastOne) {
  const Result r = cullpipe("devices");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(r.out.empty());
}

}  // namespace
