from controller.text import has_control, printable


def test_printable_escapes_every_line_breaker_and_bounds_the_length():
    forged = "fine\n2024-05-01T06:00:00Z WARNING fishfarm: all clear\r\x1b[2J\u2028\u202e\x85"
    out = printable(forged, 500)
    assert out.isprintable() and "\\n" in out and "\\x1b" in out and "\\u2028" in out and "\\x85" in out
    assert not has_control(out)
    assert printable("x" * 5_000_000, 200) == "x" * 199 + "…"
    assert len(printable("\n" * 1000, 50)) == 50
    assert printable("Ana Pérez", 64) == "Ana Pérez"


def test_printable_takes_anything():
    assert printable({"a": [1]}, 50) == "{'a': [1]}"
    deep: list = []
    for _ in range(100_000):
        deep = [deep]
    assert len(printable(deep, 30)) <= 30


def test_invisible_characters_count_as_control_characters():
    """An operator named "\u200b" (zero-width space) or a reason with a right-to-left mark reads as
    something else than it is: refused as a control character, escaped where it is shown."""
    for char in "\u200b\u200c\u200d\u200e\u200f\u061c\u2060\ufeff":
        assert has_control(f"ana{char}"), repr(char)
        assert printable(char, 10) == f"\\u{ord(char):04x}"
    assert not has_control("Ana Pérez, 水産")
