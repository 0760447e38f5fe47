// Serves one TRANSFORM message, built with the OpenIGTLink C++ library, to the first client, then waits
// for the client to close. The matrix is given as 12 float32 bit patterns (column by column, rotation then
// translation). Usage: igtl_transform_server PORT DEVICE HEX*12
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <igtlServerSocket.h>
#include <igtlTransformMessage.h>

int main(int argc, char* argv[]) {
  if (argc != 15) { std::fprintf(stderr, "usage: %s PORT DEVICE HEX*12\n", argv[0]); return 2; }
  igtl::Matrix4x4 matrix;
  igtl::IdentityMatrix(matrix);
  for (int i = 0; i < 12; ++i) {
    unsigned int bits = static_cast<unsigned int>(std::strtoul(argv[3 + i], nullptr, 16));
    std::memcpy(&matrix[i % 3][i / 3], &bits, sizeof bits);
  }
  igtl::ServerSocket::Pointer server = igtl::ServerSocket::New();
  if (server->CreateServer(std::atoi(argv[1])) < 0) { std::fprintf(stderr, "cannot listen\n"); return 1; }
  std::printf("listening\n");
  std::fflush(stdout);
  igtl::Socket::Pointer client;
  for (int attempt = 0; attempt < 100 && !client.IsNotNull(); ++attempt) client = server->WaitForConnection(100);
  if (!client.IsNotNull()) return 1;
  igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
  message->SetDeviceName(argv[2]);
  message->SetMatrix(matrix);
  message->Pack();
  client->Send(message->GetPackPointer(), message->GetPackSize());
  char byte;
  client->SetReceiveTimeout(5000);
  client->Receive(&byte, 1);  // returns when the client closes (or after 5 s)
  client->CloseSocket();
  return 0;
}
