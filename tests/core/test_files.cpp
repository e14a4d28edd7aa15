// Writing outputs without losing anything: temporary names never replace an existing file,
// finished files never replace anything but a regular file, and a video that could not be
// written completely is not moved into place.

#include "pbve/core/files.hpp"

#include <sys/resource.h>
#include <sys/stat.h>

#include <csignal>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::test::read_text;
using pbve::test::TempDir;
using pbve::test::write_text;

void write_string(const fs::path& path, const std::string& text) {
  pbve::write_atomically(path, [&](const fs::path& tmp) { write_text(tmp, text); });
}

TEST(Files, TemporaryNamesNeverReplaceAnExistingFile) {
  TempDir dir;
  // Files that happen to have the first two temporary names of out.txt.
  write_text(dir / "out.partial.txt", "one");
  write_text(dir / "out.partial-2.txt", "two");
  EXPECT_EQ(pbve::reserve_partial(dir / "out.txt"), dir / "out.partial-3.txt");
  fs::remove(dir / "out.partial-3.txt");
  write_string(dir / "out.txt", "result");
  EXPECT_EQ(read_text(dir / "out.txt"), "result");
  EXPECT_EQ(read_text(dir / "out.partial.txt"), "one");
  EXPECT_EQ(read_text(dir / "out.partial-2.txt"), "two");
  EXPECT_FALSE(fs::exists(dir / "out.partial-3.txt"));
}

TEST(Files, AFailedWriteLeavesNothing) {
  TempDir dir;
  write_text(dir / "out.txt", "before");
  EXPECT_THROW(pbve::write_atomically(dir / "out.txt",
                                      [](const fs::path&) { throw std::runtime_error("no"); }),
               std::runtime_error);
  EXPECT_EQ(read_text(dir / "out.txt"), "before");
  EXPECT_FALSE(fs::exists(dir / "out.partial.txt"));
}

TEST(Files, OnlyARegularFileIsReplaced) {
  TempDir dir;
  const fs::path pipe = dir / "pipe";
  ASSERT_EQ(::mkfifo(pipe.c_str(), 0644), 0);
  fs::create_directory(dir / "folder");
  for (const auto& [path, what] : {std::pair{pipe, "a pipe"}, std::pair{dir / "folder", "a folder"},
                                   std::pair{fs::path("/dev/null"), "a device"}}) {
    try {
      pbve::check_writable(path);
      ADD_FAILURE() << "no error for " << path;
    } catch (const pbve::InputError& e) {
      EXPECT_NE(
          std::string(e.what()).find(std::string("is ") + what + ", not a file it can replace"),
          std::string::npos)
          << e.what();
    }
  }
  EXPECT_THROW(write_string(pipe, "text"), pbve::InputError);
  EXPECT_TRUE(fs::is_fifo(pipe));
  EXPECT_FALSE(fs::exists(dir / "pipe.partial"));
  EXPECT_TRUE(fs::is_character_file("/dev/null"));
}

TEST(Files, SameFileThroughLinksAndSpellings) {
  TempDir dir;
  write_text(dir / "a.txt", "a");
  fs::create_hard_link(dir / "a.txt", dir / "hard.txt");
  fs::create_symlink(dir / "a.txt", dir / "soft.txt");
  EXPECT_TRUE(pbve::same_file(dir / "a.txt", dir / "hard.txt"));
  EXPECT_TRUE(pbve::same_file(dir / "soft.txt", dir / "a.txt"));
  EXPECT_TRUE(pbve::same_file(dir / "sub" / ".." / "new.txt", dir / "new.txt"));
  EXPECT_FALSE(pbve::same_file(dir / "a.txt", dir / "new.txt"));
  EXPECT_FALSE(pbve::same_file(dir / "a.txt", fs::path()));
  // Two names of a file that does not exist yet, relative to the current folder.
  const fs::path cwd = fs::current_path();
  fs::current_path(dir.path());
  const bool bare = pbve::same_file("new.txt", "./new.txt");
  const bool folder = pbve::same_file("new.txt", dir / "new.txt");
  const bool other = pbve::same_file("new.txt", "./other.txt");
  fs::current_path(cwd);
  EXPECT_TRUE(bare);
  EXPECT_TRUE(folder);
  EXPECT_FALSE(other);
}

TEST(Files, AVideoThatCouldNotBeWrittenIsNotMovedIntoPlace) {
  // A file size limit makes the encoder's writes fail as on a full disk (the encoder itself
  // reports nothing); this test's process only.
  TempDir dir;
  const fs::path path = dir / "full.mp4";
  rlimit before{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &before), 0);
  const auto previous = std::signal(SIGXFSZ, SIG_IGN);
  rlimit small = before;
  small.rlim_cur = 4096;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  std::string message;
  try {
    pbve::VideoWriter writer(path, 30.0, cv::Size(160, 120));
    cv::Mat frame(120, 160, CV_8UC3);
    for (int k = 0; k < 30; ++k) {
      cv::randu(frame, 0, 255);
      writer.write(frame);
    }
    writer.close();
  } catch (const pbve::InputError& e) {
    message = e.what();
  }
  ::setrlimit(RLIMIT_FSIZE, &before);
  std::signal(SIGXFSZ, previous);
  EXPECT_NE(message.find("full.mp4: the video could not be written completely (30 frames "
                         "written"),
            std::string::npos)
      << message;
  EXPECT_FALSE(fs::exists(path));
  EXPECT_TRUE(fs::is_empty(dir.path()));
}

}  // namespace
