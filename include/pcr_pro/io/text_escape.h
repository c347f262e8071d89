/**
 * @file text_escape.h
 * @brief Bytes from files and messages made safe to quote in a one-line error or log message.
 */
#pragma once

#include <cstddef>
#include <string>

namespace pcr_pro {

/**
 * @brief A string taken from a file or a message (a header line, a chunk name, an encoding, a
 * frame id) made safe to quote in a one-line message: every byte outside printable ASCII (control
 * characters, DEL, and every byte >= 0x80, so that the result is valid UTF-8 whatever the input)
 * becomes "\xNN", and a string longer than max_length bytes is cut there with "...".
 * @param[in] text any bytes
 * @param[in] max_length most input bytes quoted
 * @return printable ASCII only
 */
std::string printable(const std::string& text, std::size_t max_length = 64);

/**
 * @brief One field of a CSV row (RFC 4180): the text as it is, or, when it holds a comma, a
 * double quote, a carriage return or a line feed, in double quotes with each double quote
 * doubled, so that a reader splits the row where the writer meant.
 */
std::string csvField(const std::string& text);

}  // namespace pcr_pro
