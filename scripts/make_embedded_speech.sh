#!/usr/bin/env bash
# Maintainers: regenerate the embedded default speech clips in doabench/data/speech/.
#
# The clips are synthesised by this project with eSpeak NG (Debian package espeak-ng) from
# sentences written for doabench, then resampled to 16 kHz mono 16-bit FLAC with SoX. Different
# voices, rates and pitches make the clips differ. Nothing comes from a third-party corpus.
#
#   sudo apt-get install -y espeak-ng sox
#   scripts/make_embedded_speech.sh
#
# Output: clip1.flac .. clip6.flac and clips.txt (voice settings and sentence of each clip).
# eSpeak NG's output varies slightly between its versions, so regenerating may change the bytes.
set -euo pipefail

for tool in espeak-ng sox; do
    command -v "$tool" >/dev/null || { echo "error: $tool not found (apt-get install -y espeak-ng sox)" >&2; exit 1; }
done

out_dir="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/doabench/data/speech"
mkdir -p "$out_dir"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

# name | voice | words per minute | pitch (0-99) | sentence
clips=(
    "clip1|en-us|160|45|The microphones on the robot head listen while the speaker walks slowly across the room."
    "clip2|en-gb+f3|150|70|Please close the window near the door before the meeting starts this afternoon."
    "clip3|en-gb-scotland|140|35|A small fan hums in the corner, but the voice is still easy to follow and to locate."
    "clip4|en-us+f2|175|60|Seven bright lamps hang above the long table where the students read their notes."
    "clip5|en-gb-x-rp+m3|130|30|Turn left at the second corridor, then walk straight until you reach the quiet library."
    "clip6|en-029+f4|165|80|Every morning the tracker follows the talker and reports where the sound is coming from."
)

: > "$tmp/clips.txt"
for entry in "${clips[@]}"; do
    IFS='|' read -r name voice rate pitch text <<< "$entry"
    espeak-ng -v "$voice" -s "$rate" -p "$pitch" -w "$tmp/$name.wav" "$text"
    # espeak-ng writes 22.05 kHz; SoX resamples with its high-quality filter; -D: no dither, so pauses stay digital silence.
    sox -D "$tmp/$name.wav" -r 16000 -c 1 -b 16 "$tmp/$name.flac" norm -3
    printf '%s.flac\tvoice=%s rate=%s pitch=%s\t%s\n' "$name" "$voice" "$rate" "$pitch" "$text" >> "$tmp/clips.txt"
done

rm -f "$out_dir"/clip*.flac
mv "$tmp"/clip*.flac "$tmp/clips.txt" "$out_dir/"
echo "wrote $(ls "$out_dir"/clip*.flac | wc -l) clips to $out_dir ($(du -ch "$out_dir"/clip*.flac | tail -1 | cut -f1))"
