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


def test_every_format_character_and_default_ignorable_counts_as_control():
    """Python's own Unicode tables: every format character (category Cf, 170 in Unicode 15: soft
    hyphen, invisible operators, the tag block...) and the default-ignorable and blank-looking ones
    a name can hide in ("bob\\u2063\\u00ad" shows as "bob"); escaped where shown, with no surrogate
    halves left in the escape."""
    import sys
    import unicodedata
    format_chars = [chr(c) for c in range(sys.maxunicode + 1) if unicodedata.category(chr(c)) == "Cf"]
    assert len(format_chars) >= 160
    others = "\u034f\u115f\u1160\u17b4\u17b5\u180b\u180f\u2800\u3164\ufe00\ufe0f\uffa0\U000e0100\U000e01ef"
    for char in [*format_chars, *others]:
        assert has_control(f"bob{char}"), f"U+{ord(char):04X}"
        shown = printable(char, 20)
        assert shown.isprintable() and not has_control(shown), f"U+{ord(char):04X}"
    for fine in ("Ana Pérez", "水産 太郎", "Ólafur Þórsson", "Zoë-Chloé", "محمد", "שרה", "Ñandú 🐟"):
        assert not has_control(fine), fine
