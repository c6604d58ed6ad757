"""report.finish fills the summary part into the prepared report in chunks (cosim.results.report._fill_in):
the text is the one whole-string replacement gives, tokens cut by a chunk's end included, and the
memory it takes does not grow with the report (whose time series grow with the run's length:
the run's process held three copies of it, the peak of a long robot-cell run)."""
from __future__ import annotations

import tracemalloc

from cosim.results import report
from cosim.results.report import LIGHT_TOKEN, TITLE_TOKEN, _fill_in


def whole(text: str, title: str, payload: str) -> str:
    return text.replace(TITLE_TOKEN, title, 2).replace(LIGHT_TOKEN, payload, 1)


def test_the_filled_in_report_is_the_whole_string_replacement(tmp_path, monkeypatch):
    text = (f"<title>{TITLE_TOKEN}</title><h1>{TITLE_TOKEN}</h1>\n" + "é,0.125;" * 400
            + f'{{"series":[1,2],"light":{LIGHT_TOKEN}}}' + " tail " + TITLE_TOKEN + LIGHT_TOKEN + "\n")
    title, payload = "iso9283 &amp; model_based — ü", '{"modes":{"model_based":{"max_mm":0.1}}}'
    source = tmp_path / "report.html.part"
    source.write_text(text, encoding="utf-8")
    expected = whole(text, title, payload)
    for chunk in (7, 22, 23, 24, 25, 26, 101, 1 << 20):  # token lengths 22 and 26: cut at every place
        monkeypatch.setattr(report, "FILL_IN_CHUNK", chunk)
        target = tmp_path / f"report_{chunk}.html"
        _fill_in(source, target, {TITLE_TOKEN: (title, 2), LIGHT_TOKEN: (payload, 1)})
        assert target.read_text(encoding="utf-8") == expected, chunk


def test_filling_in_a_large_report_takes_a_few_chunks_of_memory(tmp_path):
    source = tmp_path / "report.html.part"
    with open(source, "w", encoding="utf-8") as out:
        out.write(f"<title>{TITLE_TOKEN}</title>")
        block = ("0.123456789," * (1 << 17))[:1 << 20]
        for _ in range(40):  # 40 MiB of series
            out.write(block)
        out.write(f'"light":{LIGHT_TOKEN}}}')
    target = tmp_path / "report.html"
    tracemalloc.start()
    try:
        _fill_in(source, target, {TITLE_TOKEN: ("t", 2), LIGHT_TOKEN: ("{}", 1)})
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert target.stat().st_size > 40 * 10**6
    assert peak < 8 * 2**20, peak  # a few 1 MiB chunks, not the 40 MB text
