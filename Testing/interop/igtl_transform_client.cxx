// Receives TRANSFORM messages from an OpenIGTLink server with the OpenIGTLink C++ library and prints, per message,
// the device name, the matrix's 12 float32 values as hexadecimal bit patterns (bit-exact comparison in the
// tests) and the time it arrived (s, steady clock; for rate measurements).
// Usage: igtl_transform_client HOST PORT COUNT
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <igtlClientSocket.h>
#include <igtlMessageHeader.h>
#include <igtlTransformMessage.h>

int main(int argc, char* argv[]) {
  if (argc != 4) { std::fprintf(stderr, "usage: %s HOST PORT COUNT\n", argv[0]); return 2; }
  igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
  if (socket->ConnectToServer(argv[1], std::atoi(argv[2])) != 0) { std::fprintf(stderr, "cannot connect\n"); return 1; }
  int wanted = std::atoi(argv[3]);
  for (int received = 0; received < wanted;) {
    igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
    header->InitPack();
    if (socket->Receive(header->GetPackPointer(), header->GetPackSize()) != header->GetPackSize()) return 1;
    header->Unpack();
    if (std::strcmp(header->GetDeviceType(), "TRANSFORM") != 0) {
      socket->Skip(header->GetBodySizeToRead(), 0);
      continue;
    }
    igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
    message->SetMessageHeader(header);
    message->AllocatePack();
    socket->Receive(message->GetPackBodyPointer(), message->GetPackBodySize());
    if (!(message->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) { std::fprintf(stderr, "bad CRC\n"); return 1; }
    igtl::Matrix4x4 matrix;
    message->GetMatrix(matrix);
    std::printf("%s", message->GetDeviceName());
    for (int column = 0; column < 4; ++column)
      for (int row = 0; row < 3; ++row) {
        unsigned int bits;
        std::memcpy(&bits, &matrix[row][column], sizeof bits);
        std::printf(" %08x", bits);
      }
    double now = std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
    std::printf(" %.6f\n", now);
    std::fflush(stdout);
    ++received;
  }
  socket->CloseSocket();
  return 0;
}
