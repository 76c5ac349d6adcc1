import pytest

from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError


def test_keys_values_comments_and_bools(tmp_path):
    f = tmp_path / "args.txt"
    f.write_text("# a comment line\n--num_envs 8\n--devices cpu cpu\n--visualize false\n--lr 1e-4 # trailing\n")
    p = ArgParser()
    p.load_args(["--arg_file", str(f), "--num_envs", "2", "--flag", "T"])
    assert p.parse_int("num_envs") == 2  # the command line wins over the file
    assert p.parse_strings("devices") == ["cpu", "cpu"]
    assert p.parse_bool("visualize", True) is False
    assert p.parse_bool("flag") is True
    assert p.parse_float("lr") == pytest.approx(1e-4)
    assert p.parse_string("missing", "dflt") == "dflt"


def test_empty_value_falls_back_to_default():
    p = ArgParser()
    p.load_args(["--model_file"])
    assert p.has_key("model_file")
    assert p.parse_string("model_file", "") == ""


def test_negative_numbers_are_values():
    p = ArgParser()
    p.load_args(["--offset", "-1", "-2.5"])
    assert p.parse_strings("offset") == ["-1", "-2.5"]


def test_bad_int_names_key():
    p = ArgParser()
    p.load_args(["--num_envs", "many"])
    with pytest.raises(MimicKitError, match="--num_envs"):
        p.parse_int("num_envs")


def test_missing_arg_file():
    with pytest.raises(MimicKitError, match="nope.txt"):
        ArgParser().load_args(["--arg_file", "nope.txt"])
