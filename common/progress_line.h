// Progress of long work on standard error, as the command-line tools report it: on a terminal one
// line redrawn in place; in a log (not a terminal) a line per stage and nothing for the steps
// within it, so that a log reads as a list of what was done.
//
//   ProgressLine progress(std::cerr, ::isatty(2));
//   progress.Stage("beckmann, normal incidence");   // a new line in a log; redraws on a terminal
//   progress.Step("local fit 2 of 4");              // redraws on a terminal; nothing in a log
//   progress.Done();                                 // clears the terminal's line
//
// Not thread-safe: one thread reports.
#pragma once

#include <cstddef>
#include <ostream>
#include <string>
#include <string_view>

namespace gonio {

class ProgressLine {
 public:
  // `width`: the most characters a terminal line may take (longer text is cut, so the line never
  // wraps and the redraw stays on one line).
  ProgressLine(std::ostream& out, bool terminal, std::size_t width = 100)
      : out_(out), terminal_(terminal), width_(width) {}
  ~ProgressLine() { Done(); }
  ProgressLine(const ProgressLine&) = delete;
  ProgressLine& operator=(const ProgressLine&) = delete;

  bool terminal() const { return terminal_; }

  // A stage begins: a line of its own in a log; the terminal's line shows it.
  void Stage(std::string_view text) {
    stage_ = std::string(text);
    if (terminal_)
      Draw(stage_);
    else
      out_ << text << '\n' << std::flush;
  }

  // A step within the stage: the terminal's line shows "stage: step"; a log gets nothing.
  void Step(std::string_view text) {
    if (!terminal_) return;
    Draw(stage_.empty() ? std::string(text) : stage_ + ": " + std::string(text));
  }

  // The work is over: the terminal's line is cleared, so what follows starts on a clean line.
  void Done() {
    if (terminal_ && drawn_) out_ << "\r\033[K" << std::flush;
    drawn_ = false;
  }

 private:
  void Draw(const std::string& text) {
    const std::string shown =
        text.size() < width_ ? text : text.substr(0, width_ > 4 ? width_ - 4 : 0) + "...";
    out_ << "\r\033[K" << shown << std::flush;
    drawn_ = true;
  }

  std::ostream& out_;
  bool terminal_;
  std::size_t width_;
  std::string stage_;
  bool drawn_ = false;
};

}  // namespace gonio
