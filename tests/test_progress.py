"""Progress of long work: done / total, rate (compiling left out) and time left; in place on a
terminal, plain lines elsewhere; and the run's figures led by what matters."""

import io

import pytest

import vmp.progress as progress_module
from vmp.progress import Progress, duration
from vmp.results import format_metrics


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    """A clock the test moves, and the seconds compiling it reports."""

    def __init__(self, monkeypatch) -> None:
        self.now, self.compiled = 100.0, 0.0
        monkeypatch.setattr(progress_module.time, "perf_counter", lambda: self.now)
        monkeypatch.setattr(progress_module, "compile_seconds", lambda: self.compiled)
        monkeypatch.setattr(progress_module, "compiling", lambda: False)


def test_a_terminal_line_shows_done_of_total_the_rate_without_compiling_and_time_left(
        monkeypatch):
    clock, out = Clock(monkeypatch), Terminal()
    p = Progress(1000, "mapping intel", stream=out)
    assert "0/1000 scans" in out.getvalue()
    clock.now += 30.0
    clock.compiled = 20.0  # 20 s of the 30 compiling: the work ran 10 s
    p.update(100)
    last = out.getvalue().split("\r")[-1]
    assert "100/1000 scans" in last and "10/s" in last and "1 min 30 s left" in last
    p.close()
    assert out.getvalue().endswith("\n")


def test_without_a_terminal_plain_lines_come_at_tenths_but_not_within_seconds(monkeypatch):
    clock, out = Clock(monkeypatch), io.StringIO()
    p = Progress(100, "mapping office", stream=out)
    for _ in range(30):  # 30 % in 3 s: too soon for a line
        clock.now += 0.1
        p.update()
    assert out.getvalue() == ""
    for _ in range(70):  # the rest at a scan a second
        clock.now += 1.0
        p.update()
    p.close()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue() and 5 <= len(lines) <= 12
    assert lines[0].startswith("mapping office 3") and "(3" in lines[0]  # after 5 s
    assert lines[-1].startswith("mapping office 100/100 scans (100 %)")


def test_the_first_compile_is_told_above_the_line_while_it_is_shown(monkeypatch):
    import milestones.jit as jit

    Clock(monkeypatch)
    monkeypatch.setattr(jit._CLOCK, "told", False)
    out = Terminal()
    p = Progress(10, "mapping lab", stream=out)
    assert jit._CLOCK.tell == p.note
    jit._CLOCK.on_start(None)  # what Numba does when a kernel starts compiling
    jit._CLOCK.on_end(None)
    p.close()
    assert jit._CLOCK.tell is None
    text = out.getvalue()
    assert "\r\033[Kcompiling kernels once, cached in " in text
    assert text.rstrip().split("\r")[-1].startswith("mapping lab")


def test_a_quiet_progress_writes_nothing(monkeypatch):
    Clock(monkeypatch)
    out = Terminal()
    p = Progress(10, "mapping", stream=out, enabled=False)
    p.update(5)
    p.close()
    assert out.getvalue() == ""


@pytest.mark.parametrize(("seconds", "text"), [(0.4, "0 s"), (42, "42 s"), (185, "3 min 05 s"),
                                               (3720, "1 h 02 min")])
def test_durations_read_as_a_person_says_them(seconds, text):
    assert duration(seconds) == text


def test_the_metrics_table_leads_with_accuracy_size_time_speed_and_loops():
    metrics = {"source": "office", "version": "0", "anchor matches accepted": 2204,
               "loop searches": 90, "scans": 2221, "scan odometry: refined increments": 2210,
               "milestones recorded": 97, "loop edges in the graph": 105,
               "ATE odometry alone (m)": 0.57, "mapping time (s)": 3.3,
               "scans per second": 670.0, "ATE (m)": 0.013, "data duration (s)": 222.0,
               "a figure of no group": 1}
    short = format_metrics(metrics).splitlines()
    names = [line.split("  ")[0].strip() for line in short[2:]]
    assert names[:7] == ["ATE (m)", "ATE odometry alone (m)", "scans", "data duration (s)",
                         "mapping time (s)", "scans per second", "loop edges in the graph"]
    assert short[-1] == "(5 more figures in metrics.json; --verbose prints them)"
    full = format_metrics(metrics, verbose=True)
    for heading, name in [("scan odometry:", "scan odometry: refined increments"),
                          ("anchor matches:", "anchor matches accepted"),
                          ("loop search:", "loop searches"), ("map:", "milestones recorded"),
                          ("other:", "a figure of no group")]:
        assert full.index(heading) < full.index(name)
    assert "source" not in full.split() and "version" not in full.split()
